import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# examples/ and benchmarks/ are scripts, importable by tests that check them
for sub in ("examples", "benchmarks"):
    p = str(ROOT / sub)
    if p not in sys.path:
        sys.path.insert(0, p)
