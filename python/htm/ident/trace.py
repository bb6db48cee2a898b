"""The decision trace of a diagnosis and the time its stages take.

`Trace` collects `Decision`s — the round, the stage (base fit, screen, refit, judge, break ties,
backward check, probes, verdict), the candidate, the rule applied, its outcome and the numbers it
compared — for report.json (`trace`) and, briefly, report.md. A decision whose deciding number
lies within `SearchSettings.close_margin` of its threshold, or between two candidates the record
cannot tell apart, is marked `close` and names the other candidate.

`Stages` times the stages (`stage_seconds` in the run statistics) and tells a progress callback
when each begins (`htm diagnose` prints one line per stage on stderr).
"""
from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator

Progress = Callable[[str], None]


def _num(v: Any) -> Any:
    if isinstance(v, float):
        return float(f"{v:.6g}")
    if isinstance(v, (list, tuple)):
        return [_num(x) for x in v]
    return v


@dataclass
class Decision:
    """One decision of the search: what was decided about `candidate` in `stage` of `round`, by
    which `rule`, and the numbers the rule compared."""

    round: int
    stage: str
    candidate: str | None
    rule: str
    outcome: str
    numbers: dict[str, Any] = field(default_factory=dict)
    close: bool = False
    other: str | None = None  # the other candidate of a close decision between two

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"round": self.round, "stage": self.stage, "candidate": self.candidate, "rule": self.rule,
                               "outcome": self.outcome, "numbers": {k: _num(v) for k, v in self.numbers.items()}}
        if self.close:
            out["close"] = True
        if self.other is not None:
            out["other"] = self.other
        return out

    def text(self) -> str:
        nums = ", ".join(f"{k} {_fmt(v)}" for k, v in self.numbers.items())
        who = f"{self.candidate}: " if self.candidate else ""
        close = f" — CLOSE{' against ' + self.other if self.other else ''}" if self.close else ""
        return f"round {self.round} {self.stage}: {who}{self.outcome} [{self.rule}]{' (' + nums + ')' if nums else ''}{close}"


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k}: {_fmt(x)}" for k, x in v.items()) + "}"
    return str(v)


@dataclass
class Trace:
    """The decisions of one diagnosis, in order."""

    decisions: list[Decision] = field(default_factory=list)
    round: int = 0

    def add(self, stage: str, candidate: str | None, rule: str, outcome: str, *, close: bool = False,
            other: str | None = None, **numbers: Any) -> Decision:
        d = Decision(self.round, stage, candidate, rule, outcome, numbers, close, other)
        self.decisions.append(d)
        return d

    def to_json(self) -> list[dict[str, Any]]:
        return [d.to_json() for d in self.decisions]

    def lines(self) -> list[str]:
        return [d.text() for d in self.decisions]


class Stages:
    """Wall time, CPU time (the process's, all its threads) and simulations per stage, and a
    progress line as each begins (with the CPU seconds and simulations spent so far).
    `count`, if given, returns the simulations run so far."""

    def __init__(self, progress: Progress | None = None, t0: float | None = None,
                 count: Callable[[], int] | None = None) -> None:
        self.seconds: dict[str, float] = {}
        self.cpu: dict[str, float] = {}
        self.simulations: dict[str, int] = {}
        self.progress = progress
        self.count = count if count is not None else (lambda: 0)
        self.t0 = time.perf_counter() if t0 is None else t0

    @contextmanager
    def __call__(self, stage: str, detail: str = "") -> Iterator[None]:
        t, c, n = time.perf_counter(), time.process_time(), self.count()
        if self.progress is not None:
            self.progress(f"[{t - self.t0:6.1f} s] {stage}{': ' + detail if detail else ''}"
                          f"  (cpu {c:.1f} s, {n} simulations so far)")
        try:
            yield
        finally:
            self.seconds[stage] = self.seconds.get(stage, 0.0) + time.perf_counter() - t
            self.cpu[stage] = self.cpu.get(stage, 0.0) + time.process_time() - c
            self.simulations[stage] = self.simulations.get(stage, 0) + self.count() - n

    def rounded(self) -> dict[str, float]:
        return {k: round(v, 3) for k, v in self.seconds.items()}

    def cpu_rounded(self) -> dict[str, float]:
        return {k: round(v, 3) for k, v in self.cpu.items()}
