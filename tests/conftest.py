import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# examples/ and benchmarks/ are scripts, importable by tests that check them
for sub in ("examples", "benchmarks"):
    p = str(ROOT / sub)
    if p not in sys.path:
        sys.path.insert(0, p)



@pytest.fixture(autouse=True)
def _isolated_store(tmp_path_factory, monkeypatch):
    """`htm run` records into a test store: never the developer's own."""
    monkeypatch.setenv("HTM_STORE", str(tmp_path_factory.mktemp("store")))
    monkeypatch.delenv("HTM_CLUSTER", raising=False)  # `htm campaign` runs here unless a test says otherwise


@pytest.fixture()
def store(tmp_path, monkeypatch):
    """A test store of its own for a test that reads it back (the console's tests)."""
    monkeypatch.setenv("HTM_STORE", str(tmp_path / "store"))
    return tmp_path / "store"
