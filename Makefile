# The README's two commands are `make run` and `make test`; both set up everything first.
VENV ?= .venv
PY := $(VENV)/bin/python
SOURCES := $(shell find crates python -name '*.rs' -o -name '*.py' -o -name '*.pyi') Cargo.toml crates/htm-core/Cargo.toml pyproject.toml

.PHONY: setup run test test-rust test-python bench lint clean

setup: $(VENV)/.installed

$(VENV)/.installed: $(SOURCES)
	test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e ".[dev]"
	touch $@

run: setup
	$(VENV)/bin/htm simulate --controller position_pff --kp -150 --kff -14.3 --rate 500 \
	  --profile "hold:value=0.1,duration=0.5;ramp:start=0.1,end=0.15,duration=1;hold:value=0.15,duration=0.5;sine:amplitude=0.01,frequency=2,offset=0.15,duration=2" \
	  --out out/demo-$$(date +%Y%m%d-%H%M%S)

test: setup test-rust test-python

test-rust:
	cargo test --release --quiet

test-python: setup
	$(PY) -m pytest -q

bench: setup
	$(PY) benchmarks/plant_throughput.py

clean:
	rm -rf $(VENV) target out
