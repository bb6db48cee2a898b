"""What every htm report is made of: plots drawn off-screen (matplotlib's Agg backend, loaded on
first use), Markdown tables, and a Markdown report written with a standalone HTML twin whose
plots are embedded. The reports themselves (E647 and test reports in `htm.fatigue.report`, the
diagnosis in `htm.ident.report`, a campaign's life plot) say what they show; this says how.
"""
from __future__ import annotations

import base64
import html
import threading
from pathlib import Path
from typing import Any

__all__ = ["pyplot", "preload", "save", "envelope", "md_table", "markdown_to_html", "write"]


_PRELOAD: list[threading.Thread] = []


def preload() -> None:
    """Begin importing matplotlib.pyplot (Agg) on a background thread, once: a caller that draws
    after a long computation that releases the GIL (a diagnosis: the core's simulations) then
    finds the import (~0.5 s of a report's writing) done. `pyplot()` waits for it; an import
    that fails there fails again, with its message, in `pyplot()`."""
    if not _PRELOAD:
        def load() -> None:
            try:
                pyplot()
            except Exception:  # reported by the caller's own pyplot()
                pass

        _PRELOAD.append(threading.Thread(target=load, name="htm-preload-matplotlib", daemon=True))
        _PRELOAD[0].start()


def pyplot() -> Any:
    """matplotlib.pyplot on the Agg backend (files only, no display; imported on first use)."""
    if _PRELOAD and _PRELOAD[0] is not threading.current_thread():
        _PRELOAD[0].join()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save(fig: Any, path: str | Path, dpi: int = 110) -> Path:
    """Write `fig` as PNG to `path` (its folder made) and close it; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    pyplot().close(fig)
    return path


def envelope(x: Any, y: Any, columns: int = 1500) -> tuple[Any, Any]:
    """A long line reduced to what a plot of `columns` pixel columns shows: per column of samples,
    its lowest and highest point in their order (the drawn line looks the same, every spike kept;
    a 60 s record at 500 Hz draws in a third of the time). Short lines are returned as they are."""
    import numpy as np

    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    n = len(y)
    if n <= 4 * columns:
        return x, y
    width = n // columns  # columns of `width` samples, the last one taking the rest
    cut = width * (columns - 1)
    body = y[:cut].reshape(columns - 1, width)
    start = np.arange(columns - 1) * width
    lo = np.r_[start + np.argmin(body, axis=1), cut + np.argmin(y[cut:])]
    hi = np.r_[start + np.argmax(body, axis=1), cut + np.argmax(y[cut:])]
    keep = np.column_stack([np.minimum(lo, hi), np.maximum(lo, hi)]).ravel()
    return x[keep], y[keep]


def md_table(header: list[str], rows: list[list]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(out)


def markdown_to_html(md: str, images: dict[str, Path], title: str) -> str:
    """Minimal Markdown (headings, tables, lists, paragraphs, images) to standalone HTML; images are
    embedded as base64 PNG."""
    body: list[str] = []
    lines = md.splitlines()
    i = 0
    while i < len(lines):
        ln = lines[i]
        if ln.startswith("|"):
            rows = []
            while i < len(lines) and lines[i].startswith("|"):
                if not set(lines[i].replace("|", "").strip()) <= set("-: "):
                    rows.append([c.strip() for c in lines[i].strip().strip("|").split("|")])
                i += 1
            body.append("<table>" + "".join(
                "<tr>" + "".join(f"<{'th' if j == 0 else 'td'}>{html.escape(c)}</{'th' if j == 0 else 'td'}>" for c in r) + "</tr>"
                for j, r in enumerate(rows)) + "</table>")
            continue
        if ln.startswith("!["):
            name = ln[ln.index("(") + 1:ln.index(")")]
            p = images.get(name)
            if p is not None and Path(p).exists():
                data = base64.b64encode(Path(p).read_bytes()).decode()
                body.append(f'<p><img alt="{html.escape(name)}" src="data:image/png;base64,{data}"></p>')
        elif ln.startswith("#"):
            lvl = len(ln) - len(ln.lstrip("#"))
            body.append(f"<h{lvl}>{html.escape(ln[lvl:].strip())}</h{lvl}>")
        elif ln.startswith("- "):
            body.append(f"<ul><li>{html.escape(ln[2:])}</li></ul>")
        elif ln.strip():
            body.append(f"<p>{html.escape(ln)}</p>")
        i += 1
    css = ("body{font-family:sans-serif;max-width:60em;margin:2em auto;}table{border-collapse:collapse;font-size:90%}"
           "td,th{border:1px solid #bbb;padding:2px 6px;text-align:right}img{max-width:100%}")
    return f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title><style>{css}</style></head><body>{''.join(body)}</body></html>"


def write(out: str | Path, markdown: str, title: str, images: list[Path] | None = None) -> tuple[Path, Path]:
    """Write OUT/report.md and OUT/report.html (the `images`, referenced in the Markdown by file
    name, embedded); returns both paths."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    md_path, html_path = out / "report.md", out / "report.html"
    md_path.write_text(markdown)
    html_path.write_text(markdown_to_html(markdown, {Path(p).name: Path(p) for p in images or []}, title))
    return md_path, html_path
