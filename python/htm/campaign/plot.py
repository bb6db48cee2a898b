"""The campaign's summary plot: life against each swept or scattered field (PNG)."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from htm.report import pyplot, save


def life_plot(path: Path, rows: list[dict[str, Any]], fields: list[str], title: str) -> Path:
    """One panel per field: life [cycles] of each test (valid ●, not valid ×) against the field."""
    fields = fields or ["idx"]
    ncol = min(3, len(fields))
    nrow = math.ceil(len(fields) / ncol)
    fig, axes = pyplot().subplots(nrow, ncol, figsize=(4.2 * ncol, 3.4 * nrow), squeeze=False)
    for ax, f in zip(axes.flat, fields):
        for valid, marker, label in ((True, "o", "valid"), (False, "x", "not valid")):
            pts = [(r[f], r["life_cycles"]) for r in rows if r["valid"] == valid and r["life_cycles"] and f in r]
            if pts:
                ax.scatter(*zip(*pts), marker=marker, s=14, alpha=0.7, label=label)
        ax.set_xlabel(f if f != "idx" else "test index")
        ax.set_ylabel("life [cycles]")
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
    for ax in list(axes.flat)[len(fields):]:
        ax.set_visible(False)
    axes.flat[0].legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    return save(fig, path)
