"""A small, fast line plot for the console: series drawn with braille dots (2×4 per cell) by numpy,
so a screen of plots costs well under a millisecond to redraw."""
from __future__ import annotations

import math

import numpy as np
from rich.text import Text
from textual.widget import Widget

# braille dot bit for (column 0..1, row 0..3) inside a cell
_BITS = np.array([[0x01, 0x02, 0x04, 0x40], [0x08, 0x10, 0x20, 0x80]], dtype=np.int32)
COLORS = ("cyan", "magenta", "yellow", "yellow", "green", "red")


def _fmt(v: float) -> str:
    return f"{v:.4g}" if math.isfinite(v) else "–"


def axis_labels(lo: float, hi: float, n: int = 2) -> list[str]:
    """`n` labels from `lo` to `hi`, with as many decimals as the range needs for them to differ
    (a crack at 15.20 … 15.24 mm reads so, not "15.2" twice); thousands grouped; at most 8 wide."""
    vals = [lo + (hi - lo) * i / (n - 1) for i in range(n)] if n > 1 else [lo]
    if not all(math.isfinite(v) for v in vals):
        return [_fmt(v) for v in vals]
    span = abs(hi - lo) / max(n - 1, 1)
    big = max(abs(lo), abs(hi))
    if big >= 1e7 or (0 < big < 1e-3):
        return [f"{v:.3g}" for v in vals]
    decimals = 0 if span <= 0 else max(0, -math.floor(math.log10(span)) + 1)
    if span > 0 and span >= 10:
        decimals = 0
    decimals = min(decimals, 6)
    out = [f"{v:,.{decimals}f}" for v in vals]
    while decimals > 0 and max(map(len, out)) > 8:
        decimals -= 1
        out = [f"{v:,.{decimals}f}" for v in vals]
    return [o.replace("-", "−") if o.strip("-0.,") else o.lstrip("-") for o in out]


class LinePlot(Widget):
    """`title` on top, y range on the left, series as coloured braille lines."""

    DEFAULT_CSS = "LinePlot { height: 1fr; min-height: 6; border: round $panel; }"

    def __init__(self, title: str = "", **kw) -> None:
        super().__init__(**kw)
        self.title = title
        self.series: list[tuple[np.ndarray, np.ndarray, str]] = []
        # a path (a hysteresis loop: x goes back and forth) is drawn along its samples, not as y(x)
        self.path = False

    def set_series(self, series: list[tuple[list[float] | np.ndarray, list[float] | np.ndarray, str]]) -> None:
        self.series = [(np.asarray(x, float), np.asarray(y, float), label) for x, y, label in series if len(x)]
        self.refresh()

    def render(self) -> Text:
        w, h = max(self.size.width - 9, 4), max(self.size.height - 2, 2)
        out = Text(self.title[: w + 8] + "\n", style="bold")
        pts = [(x[m], y[m]) for x, y, _ in self.series for m in [np.isfinite(x) & np.isfinite(y)]]
        if not any(len(x) for x, _ in pts):
            out.append("(no data yet)", style="dim")
            return out
        xs = np.concatenate([x for x, _ in pts])
        ys = np.concatenate([y for _, y in pts])
        x0, x1 = float(xs.min()), float(xs.max())
        y0, y1 = float(ys.min()), float(ys.max())
        if x1 <= x0:
            x1 = x0 + 1.0
        if y1 <= y0:
            y0, y1 = y0 - 0.5, y1 + 0.5
        cells = np.zeros((h, w), np.int32)
        owner = np.full((h, w), -1, np.int32)
        for i, (x, y) in enumerate(pts):
            if not len(x):
                continue
            # densify so lines stay connected: one point per dot column (a path: along its samples)
            if self.path and len(x) > 1:
                t = np.arange(len(x), dtype=float)
                td = np.linspace(0.0, len(x) - 1.0, 8 * w)
                xd, yd = np.interp(td, t, x), np.interp(td, t, y)
            else:
                xd = np.linspace(x0, x1, 2 * w) if len(x) > 1 else x
                yd = np.interp(xd, x, y, left=np.nan, right=np.nan) if len(x) > 1 else y
            ok = np.isfinite(yd)
            cx = np.clip(((xd[ok] - x0) / (x1 - x0) * (2 * w - 1)).round().astype(int), 0, 2 * w - 1)
            cy = np.clip(((y1 - yd[ok]) / (y1 - y0) * (4 * h - 1)).round().astype(int), 0, 4 * h - 1)
            np.bitwise_or.at(cells, (cy // 4, cx // 2), _BITS[cx % 2, cy % 4])
            owner[cy // 4, cx // 2] = i
        top, mid, bottom = axis_labels(y0, y1, 3)[::-1]
        for r in range(h):
            label = top if r == 0 else bottom if r == h - 1 else mid if h >= 5 and r == (h - 1) // 2 and (h - 1) % 2 == 0 else ""
            out.append(f"{label:>8} ", style="dim")
            for c in range(w):
                v = cells[r, c]
                out.append(chr(0x2800 + int(v)) if v else " ", style=COLORS[owner[r, c] % len(COLORS)] if v else None)
            out.append("\n")
        legend = "  ".join(f"[{COLORS[i % len(COLORS)]}]■[/] {lab}" for i, (_, _, lab) in enumerate(self.series))
        left, right = axis_labels(x0, x1)
        out.append_text(Text.from_markup(f"{' ' * 9}{left} … {right}   {legend}"))
        return out
