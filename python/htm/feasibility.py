"""Know before you start: can the rig run this test on this specimen?

The limits are computed in the Rust core (`htm.core.feasibility`, one formula per limit); this
module words them for a person: force capacity (piston areas × supply pressure, both
directions), valve flow for the waveform's peak piston speed, frequency against the oil-column /
specimen resonance, stroke, and the ASTM E647 size criterion over the crack range. A refused
check names the number that fails and the largest feasible ΔF or frequency; `htm run` refuses
such a test unless the spec sets ``[run] override_limits = true``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from htm.core import RESONANCE_FRACTION, TestConfig
from htm.core import feasibility as core_checks

TITLES = {
    "force_tension": "force capacity (tension)",
    "force_compression": "force capacity (compression)",
    "valve_flow": "valve flow",
    "frequency": "frequency",
    "stroke": "stroke",
    "size_criterion": "E647 size criterion",
}


@dataclass(frozen=True)
class Check:
    """One limit (SI): what the test needs against what the rig or specimen gives."""

    name: str
    status: str  # "ok", "marginal" or "refused"
    need: float
    limit: float
    unit: str
    phase: int
    a_m: float
    delta_f_n: float
    largest_delta_f_n: float | None
    largest_frequency_hz: float | None
    text: str  # one sentence in engineering units


@dataclass(frozen=True)
class Feasibility:
    checks: list[Check]

    @property
    def refused(self) -> list[Check]:
        return [c for c in self.checks if c.status == "refused"]

    @property
    def marginal(self) -> list[Check]:
        return [c for c in self.checks if c.status == "marginal"]

    @property
    def feasible(self) -> bool:
        return not self.refused

    def verdict(self) -> str:
        if self.refused:
            return "refused: " + ", ".join(TITLES[c.name] for c in self.refused)
        if self.marginal:
            return "feasible with warnings: " + ", ".join(TITLES[c.name] for c in self.marginal)
        return "feasible"

    def table(self) -> str:
        """One line per check: status, title, need / limit, and the sentence."""
        w = max(len(TITLES[c.name]) for c in self.checks)
        rows = [f"{c.status.upper():<8}  {TITLES[c.name]:<{w}}  {_ratio(c):>6}  {c.text}" for c in self.checks]
        return "\n".join([*rows, f"verdict: {self.verdict()}"])

    def refusal(self) -> str:
        """The message of a refused test: every failing limit with its largest feasible value."""
        return ("the rig cannot run this test — " + "; ".join(c.text for c in self.refused)
                + ". Change the spec, or set [run] override_limits = true to run it anyway "
                  "(its summary and report then state the force error it reached)")


def _ratio(c: Check) -> str:
    return f"{100 * c.need / c.limit:.0f} %" if c.limit > 0 else "—"


def _kn(f: float) -> str:
    return f"{f / 1e3:.3g} kN"


def _largest(c: Check, r_ratio: float | None) -> str:
    """How far the test could go; `r_ratio` None for a variable-amplitude sequence, whose
    limiting level is named by its ΔF (the whole sequence scales with it)."""
    parts = []
    if c.largest_frequency_hz is not None and c.name in ("valve_flow", "frequency"):
        parts.append(f"largest feasible frequency {c.largest_frequency_hz:.3g} Hz")
    if c.largest_delta_f_n is not None and c.name != "frequency":
        over = " over the whole crack range" if c.name == "size_criterion" else ""
        at = (f"at R = {r_ratio:g}, asked {_kn(c.delta_f_n)}" if r_ratio is not None else
              f"for the sequence's level of ΔF {_kn(c.delta_f_n)}: scale the sequence by {c.largest_delta_f_n / c.delta_f_n:.3g}")
        parts.append(f"largest feasible ΔF {_kn(c.largest_delta_f_n)}{over} ({at})")
    return "; ".join(parts)


def _sentence(d: dict[str, Any], config: TestConfig) -> str:
    """The check's numbers in engineering units; refused and marginal checks add how far the
    test could go."""
    name, need, limit = d["name"], d["need"], d["limit"]
    r = None if config.variable_amplitude else config.r_ratios[d["phase"]]
    a_mm = d["a_m"] * 1e3
    if name == "force_tension":
        s = (f"peak force {_kn(need)}, the actuator gives {_kn(limit)} in tension "
             "(piston area × supply pressure, less the moving weight)")
    elif name == "force_compression":
        s = f"valley force {_kn(-need)}, the actuator gives {_kn(limit)} in compression (piston area × supply pressure)"
    elif name == "valve_flow":
        s = (f"loading.frequency_hz = {config.frequency_hz:g} Hz with a {config.waveform} waveform needs a piston "
             f"speed of {need * 1e3:.1f} mm/s at the end crack length, the valve gives {limit * 1e3:.1f} mm/s "
             "at half its rated flow")
    elif name == "frequency":
        s = (f"loading.frequency_hz = {need:g} Hz, the limit is {limit:.3g} Hz: 1/{1 / RESONANCE_FRACTION:g} of the rig's "
             f"oil-column/specimen resonance ({limit / RESONANCE_FRACTION:.0f} Hz)")
    elif name == "stroke":
        s = (f"the piston travels {need * 1e3:.3g} mm from the specimen's zero-force position at a = {a_mm:.2f} mm, "
             f"{limit * 1e3:.3g} mm of stroke are left")
    else:  # size_criterion
        holds = need <= limit
        s = (f"at a = {a_mm:.2f} mm the ligament is {limit * 1e3:.2f} mm, {need * 1e3:.2f} mm required"
             + ("" if holds or d["status"] == "refused" else "; the points beyond are invalid"))
        if holds:
            s = f"holds over the whole crack range (closest at a = {a_mm:.2f} mm: ligament {limit * 1e3:.2f} mm, {need * 1e3:.2f} mm required)"
    if d["status"] != "ok":
        more = _largest(_check(d, ""), r)
        if more:
            s += f"; {more}"
    return s


def _check(d: dict[str, Any], text: str) -> Check:
    return Check(d["name"], d["status"], d["need"], d["limit"], d["unit"], d["phase"], d["a_m"], d["delta_f_n"],
                 d["largest_delta_f_n"], d["largest_frequency_hz"], text)


def assess(config: TestConfig) -> Feasibility:
    """Every feasibility check of a test's configuration (`TestSpec.config`), worded."""
    return Feasibility([_check(d, _sentence(d, config)) for d in core_checks(config)])
