# The README's two commands are `make run` and `make test`; both set up everything first.
VENV ?= .venv
PY := $(VENV)/bin/python
SOURCES := $(shell find crates python -name '*.rs' -o -name '*.py' -o -name '*.pyi') Cargo.toml crates/htm-core/Cargo.toml pyproject.toml

.PHONY: setup run test test-rust test-python bench lint docs clean

setup: $(VENV)/.installed

$(VENV)/.installed: $(SOURCES)
	test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e ".[dev]"
	touch $@

run: setup
	$(VENV)/bin/htm run examples/ct_constant_force.toml --out out/ct-$$(date +%Y%m%d-%H%M%S)

test: setup test-rust test-python

test-rust:
	cargo test --release --quiet

# the campaign tests need PostgreSQL and a Dask cluster: started here unless already running
# (.ci/run starts them once for the whole run); the slowest 20 tests are listed at the end (the run's
# budget is about 15 minutes on 2 cores: where to trim first)
test-python: setup
	if [ -n "$${HTM_TEST_PG:-}" ] && [ -n "$${HTM_TEST_DASK:-}" ]; then $(PY) -m pytest -q --durations=20; \
	else HTM_VENV=$(VENV) bash tools/services.sh $(PY) -m pytest -q --durations=20; fi

bench: setup
	$(PY) benchmarks/plant_throughput.py
	$(PY) benchmarks/million_cycles.py
	$(PY) benchmarks/recording.py

# ruff and the layers contract (pyproject.toml), clippy on the crate with its bindings, the stubs
# against the built extension
lint: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/lint-imports
	cargo clippy --release --all-targets --features python -- -D warnings
	$(PY) -m mypy.stubtest htm._core

# the documentation site (mkdocs.yml, docs/) with warnings as errors: broken links and anchors, pages
# missing from the nav, API pages whose objects or docstrings do not resolve; into out/site
docs: setup
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict --quiet

clean:
	rm -rf $(VENV) target out
