"""Timing statistics of a fixed-period loop: period start error (jitter) p50/p99/max, overruns."""
from __future__ import annotations

import numpy as np


class Timing:
    """Records each period's start error [ns] (actual − scheduled) and whether it overran."""

    def __init__(self, capacity: int = 1 << 17):
        self._err = np.zeros(capacity, dtype=np.int64)
        self.n = 0
        self.overruns = 0
        self.work_max_ns = 0

    def record(self, start_error_ns: int, work_ns: int, overrun: bool) -> None:
        self._err[self.n % len(self._err)] = start_error_ns
        self.n += 1
        self.overruns += overrun
        if work_ns > self.work_max_ns:
            self.work_max_ns = work_ns

    def stats(self) -> dict[str, float]:
        """p50/p99/max of |start error| [ms] over the last `capacity` periods, overrun count and %."""
        m = min(self.n, len(self._err))
        if m == 0:
            return {"periods": 0, "p50_ms": float("nan"), "p99_ms": float("nan"), "max_ms": float("nan"),
                    "overruns": 0, "overrun_pct": 0.0, "work_max_ms": 0.0}
        e = np.abs(self._err[:m]) / 1e6
        p50, p99 = np.percentile(e, [50, 99])
        return {"periods": self.n, "p50_ms": float(p50), "p99_ms": float(p99), "max_ms": float(e.max()),
                "overruns": self.overruns, "overrun_pct": 100.0 * self.overruns / self.n, "work_max_ms": self.work_max_ns / 1e6}
