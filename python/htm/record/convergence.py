"""Convergence of the force into the band, logged with every test (simulated and on the rig):
for the start and after every resume and stiffness step, the full-amplitude cycles until
|ΔF error| enters ±2 % and ±0.5 % and stays there, and the worst |ΔF error| of the first 20.
The numbers come from the core's cycle machine (`engine::cycle::Episode`); here they become the
summary's `convergence`, the store's results and events, and events in the rerun recording."""
from __future__ import annotations

from typing import Any


def describe(e: dict[str, Any]) -> str:
    """One line for an episode (a dict of `htm.core` `convergence`)."""
    def to(n: int | None, band: str) -> str:
        if n is None:
            return f"not inside {band}"
        return f"inside {band} from the first cycle" if n == 0 else f"inside {band} after {n} cycles"
    if not e["cycles_seen"]:
        return f"{e['cause']}: no full-amplitude cycle yet"
    return (f"{e['cause']} (cycle {e['first_cycle']:,}): {to(e['cycles_to_2pct'], '±2 %')}, "
            f"{to(e['cycles_to_0p5pct'], '±0.5 %')}; worst |ΔF| of the first 20 {e['worst_first_df_pct']:.2f} %")


def results(episodes: list[dict[str, Any]]) -> dict[str, Any]:
    """The store's result keys: the list itself and the start's figures as plain numbers."""
    out: dict[str, Any] = {"convergence": episodes}
    start = next((e for e in episodes if e["cause"] == "start" and e["cycles_seen"]), None)
    if start is not None:
        out["worst_first_cycles_df_pct"] = start["worst_first_df_pct"]
        out["cycles_to_2pct"] = start["cycles_to_2pct"]
        out["cycles_to_0p5pct"] = start["cycles_to_0p5pct"]
    return out


def log(writer: Any, episodes: list[dict[str, Any]], frequency_hz: float) -> None:
    """Every episode as a `convergence` event (catalogue and rerun recording), dated by its
    first full-amplitude cycle; a band not reached is a warning."""
    for e in episodes:
        c = e["first_cycle"] or None
        level = "INFO" if e["cycles_to_2pct"] is not None else "WARN"
        writer.event("convergence", describe(e), cycle=c, time_s=None if c is None else c / frequency_hz, level=level)
