"""Fatigue reports (drawn and written with `htm.report`): plots, the E647 reduction report, and the fatigue test report
(Table B.1-style table, a–N, da/dN–ΔK with the fitted law, ±2 % force-band statistics, specimen and
loading data, validity summary) in Markdown and standalone HTML with embedded plots."""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from htm.fatigue.data import CrackData, Setup
from htm.fatigue.e647 import Reduced, paris_region_ii, reduce, summary, threshold
from htm.fatigue.laws import Model, Points, fit_rate
from htm.report import md_table, pyplot, save, write

REDUCED_COLUMNS = ("cycles", "a_m", "a_fit_m", "dadn_m_per_cycle", "delta_k_mpa_sqrt_m", "kmax_mpa_sqrt_m", "valid", "reasons")


def write_reduced_csv(path: Path, reds: list[Reduced], with_specimen: bool) -> None:
    cols = (("specimen",) if with_specimen else ()) + REDUCED_COLUMNS
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for rd in reds:
            for i in range(len(rd)):
                row = [f"{rd.cycles[i]:.10g}", f"{rd.a_m[i]:.9g}", _g(rd.a_fit_m[i]), _g(rd.dadn_m_per_cycle[i]),
                       _g(rd.delta_k_pa_sqrt_m[i] / 1e6), _g(rd.kmax_pa_sqrt_m[i] / 1e6), int(rd.valid[i]), rd.reasons[i]]
                w.writerow(([rd.specimen] if with_specimen else []) + row)


def _g(v: float) -> str:
    return "" if not np.isfinite(v) else f"{v:.9g}"


def plot_a_n(path: Path, datas: list[CrackData], reds: list[Reduced] | None = None, model: Model | None = None,
             setup: Setup | None = None) -> Path:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for d in datas:
        ax.plot(d.cycles, d.a_m * 1e3, ".", ms=2.5, label=None if len(datas) > 6 else f"specimen {d.specimen}")
        if model is not None and setup is not None:
            try:
                curve = model.life_curve(setup, d.a_m)
                ok = np.isfinite(curve)
                ax.plot(d.cycles[0] + curve[ok], d.a_m[ok] * 1e3, "-", lw=0.8, color="k", alpha=0.6)
            except Exception:  # noqa: BLE001 — plot what can be drawn
                pass
    ax.set_xlabel("cycles N")
    ax.set_ylabel("crack size a [mm]")
    ax.grid(alpha=0.3)
    if len(datas) <= 6:
        ax.legend(fontsize=8)
    fig.tight_layout()
    return save(fig, path)


def plot_dadn_dk(path: Path, reds: list[Reduced], models: dict[str, Model] | None = None, r_ratio: float = 0.0,
                 band: float | None = None) -> Path:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    for rd in reds:
        m = rd.mask(False)
        v = m & rd.valid
        ax.loglog(rd.delta_k_pa_sqrt_m[v] / 1e6, rd.dadn_m_per_cycle[v], ".", ms=2.5, color="C0")
        ax.loglog(rd.delta_k_pa_sqrt_m[m & ~rd.valid] / 1e6, rd.dadn_m_per_cycle[m & ~rd.valid], "x", ms=3, color="C3")
    allk = np.concatenate([rd.delta_k_pa_sqrt_m[rd.mask(False)] for rd in reds])
    allkm = np.concatenate([rd.kmax_pa_sqrt_m[rd.mask(False)] for rd in reds])
    if models and allk.size:
        dk = np.geomspace(allk.min(), allk.max(), 200)
        km = dk * allkm.max() / allk.max()
        for i, (name, mod) in enumerate(models.items()):
            rate = mod.rate(dk, km, r_ratio)
            ax.loglog(dk / 1e6, rate, "-", color=f"C{i + 1}", lw=1.5, label=name)
            if band:
                ax.fill_between(dk / 1e6, rate * 10 ** -band, rate * 10 ** band, color=f"C{i + 1}", alpha=0.12)
        ax.legend(fontsize=8)
    ax.set_xlabel("ΔK [MPa·√m]")
    ax.set_ylabel("da/dN [m/cycle]")
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    return save(fig, path)


def plot_residual(path: Path, x: np.ndarray, r: np.ndarray, bins: list[dict], xlabel: str, bins_after: list[dict] | None = None) -> Path:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 3.8))
    ax.plot(x, r, ".", ms=1.5, alpha=0.3, color="0.5")
    ax.errorbar([b["x_mean"] for b in bins], [b["residual_mean"] for b in bins],
                yerr=[2 * b["residual_se"] for b in bins], fmt="o-", color="C3", label="Paris: binned mean ± 2 SE")
    if bins_after:
        ax.errorbar([b["x_mean"] for b in bins_after], [b["residual_mean"] for b in bins_after],
                    yerr=[2 * b["residual_se"] for b in bins_after], fmt="s-", color="C2", label="refit law")
    ax.axhline(0, color="k", lw=0.8)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("log10(measured / model) da/dN")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return save(fig, path)


def _opening_columns(source: str | Path | None) -> dict[str, np.ndarray] | None:
    """The opening forces of an a–N file written by `htm crack measure` (`opening_force_n`, with
    `cycles` and `a_m`); None when the file has none (any other a–N table)."""
    import csv

    if source is None:
        return None
    try:
        with open(source, newline="") as fh:
            rows = list(csv.DictReader(fh))
    except (OSError, UnicodeDecodeError, csv.Error):
        return None
    if not rows or "opening_force_n" not in rows[0] or "cycles" not in rows[0]:
        return None

    def col(k: str) -> np.ndarray:
        out = []
        for r in rows:
            try:
                out.append(float(r.get(k) or "nan"))
            except ValueError:
                out.append(np.nan)
        return np.array(out)

    return {k: col(k) for k in ("cycles", "a_m", "opening_force_n", "fmax_n", "fmin_n", "delta_k_pa_sqrt_m", "delta_k_eff_pa_sqrt_m",
                                "opening_resolved")
            if k in rows[0]}


def opening_section(cycles: np.ndarray, op: np.ndarray, pmax: np.ndarray | float, dk: np.ndarray | None = None,
                    dk_eff: np.ndarray | None = None, method: str = "E647 X2 compliance offset, 2 % criterion",
                    unresolved: int | None = None) -> list[str]:
    """The report's closure section: the opening force per measurement (range, as a share of
    Pmax) and ΔK_eff beside ΔK, with a table of up to 25 rows spread over the test; `unresolved`
    readings whose opening force the noise left undetermined are counted."""
    ok = np.isfinite(op)
    if not ok.any():
        return []
    pmax = np.broadcast_to(np.asarray(pmax, float), op.shape)
    share = op / pmax
    lines = ["## Crack closure (opening force, ΔK_eff)", "",
             f"Opening force ({method}) {np.nanmin(op[ok]) / 1e3:.4g}–{np.nanmax(op[ok]) / 1e3:.4g} kN, "
             f"{100 * np.nanmin(share[ok]):.1f}–{100 * np.nanmax(share[ok]):.1f} % of Pmax (mean {100 * np.nanmean(share[ok]):.1f} %)"]
    if dk is not None and dk_eff is not None:
        ratio = dk_eff / np.where(dk > 0, dk, np.nan)
        if np.isfinite(ratio).any():
            lines[-1] += f"; ΔK_eff/ΔK {np.nanmin(ratio):.3f}–{np.nanmax(ratio):.3f}"
    lines[-1] += "."
    if unresolved:
        lines[-1] += (f" {unresolved:,} readings leave it not resolved: the gauge's noise hides the closure there "
                      "(no opening force, ΔK_eff not claimed).")
    idx = np.flatnonzero(ok)
    idx = idx[np.unique(np.linspace(0, len(idx) - 1, min(25, len(idx))).round().astype(int))]
    head = ["N", "F_op [kN]", "F_op / Pmax"] + (["ΔK [MPa·√m]", "ΔK_eff [MPa·√m]"] if dk is not None and dk_eff is not None else [])
    rows = []
    for i in idx:
        r = [f"{cycles[i]:.6g}", f"{op[i] / 1e3:.4g}", f"{share[i]:.3f}"]
        if dk is not None and dk_eff is not None:
            r += [f"{dk[i] / 1e6:.3f}" if np.isfinite(dk[i]) else "", f"{dk_eff[i] / 1e6:.3f}" if np.isfinite(dk_eff[i]) else ""]
        rows.append(r)
    return lines + ["", md_table(head, rows), ""]


def plot_a_n_vs_law(path: Path, cycles: np.ndarray, a_m: np.ndarray, a_law_m: np.ndarray, crack: str) -> Path:
    """a–N of the crack the test ran on (measured) with the spec's law's crack beside it."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    ax.plot(cycles, a_m * 1e3, "-", lw=1.2, label=f"measured ({crack.replace('_', ' ')}): the test ran on it")
    ax.plot(cycles, a_law_m * 1e3, "--", lw=1.2, label="the spec's growth law")
    ax.set_xlabel("cycles N")
    ax.set_ylabel("crack size a [mm]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return save(fig, path)


def e647_report(out: Path, datas: list[CrackData], setup: Setup, reds: list[Reduced], n: int,
                source: str | Path | None = None) -> Path:
    """Write DIR/report.md (and plots) for an `htm e647` reduction. `source`: the a–N file, whose
    opening forces (`htm crack measure` output) the report lists when it has them."""
    out = Path(out)
    a_n = plot_a_n(out / "a_n.png", datas)
    pf = None
    try:
        pf = paris_region_ii(reds)
    except Exception:  # noqa: BLE001 — too few valid points for a fit: the report says so
        pass
    models = {}
    if pf is not None and pf.m > 0:  # a falling rate (m ≤ 0) is no Paris law: no line is drawn
        models["Paris (region II, valid points)"] = Model("paris", {"log10_c": np.log10(pf.c_mpa), "m": pf.m})
    dadn = plot_dadn_dk(out / "dadn_dk.png", reds, models, setup.r_ratio)
    lines = ["# ASTM E647 reduction", "", "## Specimen and loading", "",
             md_table(["quantity", "value"], [
                 ["geometry", setup.geometry.upper()], ["W [mm]", f"{setup.width_m * 1e3:.3f}"],
                 ["B [mm]", f"{setup.thickness_m * 1e3:.3f}"], ["ΔP [kN]", f"{setup.delta_p_n / 1e3:.4g}"],
                 ["Pmax [kN]", f"{setup.pmax_n / 1e3:.4g}"], ["R", f"{setup.r_ratio:g}"],
                 ["method", f"incremental polynomial, n = {n} ({2 * n + 1} points)"],
                 ["σ_ys", f"{setup.yield_strength_pa / 1e6:g} MPa" if setup.yield_strength_pa else "not given (size criterion not checked)"]]),
             "", "## Validity", ""]
    rows = []
    for rd in reds:
        s = summary(rd)
        th = threshold(rd)
        rows.append([rd.specimen, s["points"], s["valid"], ", ".join(f"{k}: {v}" for k, v in sorted(s["reasons"].items())) or "-",
                     f"{th['delta_k_th_pa_sqrt_m'] / 1e6:.3g} MPa·√m" if th["reached"] else "not reached"])
    lines += [md_table(["specimen", "points", "valid", "invalid reasons", "ΔK_th (E647)"], rows), ""]
    if pf is not None:
        lines += ["## Region-II Paris fit", "",
                  f"da/dN = C·ΔK^m with C = {pf.c_mpa:.4e} (m/cycle)/(MPa·√m)^m (log10 C ± {pf.se_log10_c:.3g}), "
                  f"m = {pf.m:.4f} ± {pf.se_m:.3g}; {pf.npoints} points, ΔK {pf.dk_range_mpa[0]:.3g}–{pf.dk_range_mpa[1]:.3g} MPa·√m, "
                  f"RMS log10 error {pf.rms_log10:.4f}.", ""]
    oc = _opening_columns(source)
    if oc is not None and "opening_force_n" in oc:
        pmax = oc["fmax_n"] if "fmax_n" in oc and np.isfinite(oc["fmax_n"]).any() else setup.pmax_n
        lines += opening_section(oc["cycles"], oc["opening_force_n"], pmax, oc.get("delta_k_pa_sqrt_m"), oc.get("delta_k_eff_pa_sqrt_m"),
                                 unresolved=int((oc["opening_resolved"] == 0).sum()) if "opening_resolved" in oc else None)
    lines += ["## Plots", "", f"![a-N]({a_n.name})", "", f"![da/dN-dK]({dadn.name})", ""]
    p = out / "report.md"
    p.write_text("\n".join(lines))
    return p


def force_band(pmax_meas: np.ndarray, pmin_meas: np.ndarray, pmax_n, pmin_n, band: float = 0.02) -> dict:
    """ISO 12108 / E647 ±2 % force check: fraction of cycles whose peak and valley force stay within
    ±band·ΔP of their targets (band relative to the target range), and the worst deviation. The
    targets are numbers, or arrays of each cycle's (variable-amplitude loading)."""
    pmax_n, pmin_n = np.asarray(pmax_n, float), np.asarray(pmin_n, float)
    dp = np.where(np.abs(pmax_n - pmin_n) > 0, np.abs(pmax_n - pmin_n), np.abs(pmax_n))
    e_max = (np.asarray(pmax_meas) - pmax_n) / dp
    e_min = (np.asarray(pmin_meas) - pmin_n) / dp
    inside = (np.abs(e_max) <= band) & (np.abs(e_min) <= band)
    return {"cycles": int(len(e_max)), "fraction_inside": float(inside.mean()) if len(inside) else float("nan"),
            "max_peak_dev_rel": float(np.max(np.abs(e_max))) if len(e_max) else float("nan"),
            "max_valley_dev_rel": float(np.max(np.abs(e_min))) if len(e_min) else float("nan"),
            "rms_peak_dev_rel": float(np.sqrt(np.mean(e_max ** 2))) if len(e_max) else float("nan"), "band": band}


def force_errors(table: dict, setup: Setup, band: float) -> tuple[np.ndarray, dict] | None:
    """Per-cycle force errors of a test table: the engine's `df_err_pct` and `peak_err_pct` when
    given (ΔF error over ΔF, peak error over Fmax), else from measured `pmax_n`/`pmin_n` against the
    setup's targets. Returns (mask of cycles outside ±band, the worst errors [%]) or None."""
    if "df_err_pct" in table and "peak_err_pct" in table:
        df = np.abs(np.asarray(table["df_err_pct"], float))
        pk = np.abs(np.asarray(table["peak_err_pct"], float))
    elif "pmax_n" in table and "pmin_n" in table:
        fmax, fmin = np.asarray(table["pmax_n"], float), np.asarray(table["pmin_n"], float)
        df = 100 * np.abs((fmax - fmin) / setup.delta_p_n - 1)
        pk = 100 * np.abs(fmax / setup.pmax_n - 1)
    else:
        return None
    outside = ~((df <= 100 * band) & (pk <= 100 * band))  # NaN (no measurement) counts as outside
    worst = {"max_abs_df_err_pct": float(np.nanmax(df)) if len(df) else float("nan"),
             "max_abs_peak_err_pct": float(np.nanmax(pk)) if len(pk) else float("nan"),
             "cycles_outside": int(outside.sum()), "cycles": int(len(df)), "band_pct": 100 * band}
    return outside, worst


def mark_force_band(rd: Reduced, cycles_outside: np.ndarray, n: int) -> int:
    """Mark invalid (reason `force_band`) the reduced points whose incremental-polynomial window
    (2n+1 readings) spans a cycle whose force left the band; returns how many were marked."""
    bad = np.sort(np.asarray(cycles_outside, float))
    k = len(rd)
    marked = 0
    for i in range(k):
        lo, hi = rd.cycles[max(0, i - n)], rd.cycles[min(k - 1, i + n)]
        if np.searchsorted(bad, hi, side="right") > np.searchsorted(bad, lo, side="left"):
            if rd.valid[i]:
                marked += 1
            rd.valid[i] = False
            rd.reasons[i] = ";".join(filter(None, [rd.reasons[i], "force_band"]))
    return marked


def rainflow_section(pmax: np.ndarray, pmin: np.ndarray, bins: int = 8) -> list[str]:
    """Markdown: the rainflow count (ASTM E1049, the core's) of the measured peaks and valleys,
    binned by force range."""
    from htm import core

    series = np.column_stack([np.asarray(pmax, float), np.asarray(pmin, float)]).ravel()
    counted = np.array(core.rainflow(series.tolist()))
    if not len(counted):
        return []
    rng, mean, cnt = counted[:, 0], counted[:, 1], counted[:, 2]
    edges = np.linspace(0.0, rng.max() * (1 + 1e-9), bins + 1)
    rows = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        m = (rng >= lo) & (rng < hi)
        if cnt[m].sum():
            rows.append([f"{lo / 1e3:.3f} – {hi / 1e3:.3f}", f"{cnt[m].sum():g}", f"{np.average(mean[m], weights=cnt[m]) / 1e3:.3f}"])
    return ["## Variable-amplitude loading: rainflow count (ASTM E1049)", "",
            f"{cnt.sum():g} cycles counted from {len(series):,} measured reversals; the da/dN–ΔK reduction below uses "
            "the reference level of [loading] and is indicative only under variable amplitude.", "",
            md_table(["force range [kN]", "cycles", "mean force [kN]"], rows), ""]


def write_test_report(out: str | Path, table: dict, setup: Setup, *, specimen_info: dict | None = None,
                loading_info: dict | None = None, n: int = 3, law: str = "paris", title: str = "Fatigue crack growth test",
                band: float = 0.02, variable_amplitude: bool = False, crack: str | None = None) -> dict:
    """The report of a test run (to be called by `htm run`): `table` has per-cycle or a–N columns
    `cycles`, `a_m` and optionally `pmax_n`, `pmin_n` (measured peak/valley force per cycle) and
    the engine's `df_err_pct`, `peak_err_pct`. Points whose cycles left the ±`band` force band are
    invalid (`force_band`); the report states the real force error. Writes OUT/report.md,
    OUT/report.html (plots embedded), OUT/reduced.csv and the plots; returns paths and the numbers
    reported. A test that ran on a measured crack (`crack` = "compliance" or "potential_drop")
    with the law's crack beside it (`a_law_m`) gets the a–N plot of both, and its opening forces
    (`opening_force_n`) and ΔK_eff (`delta_k_eff_pa_sqrt_m`, with `delta_k_pa_sqrt_m`) listed."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cycles = np.asarray(table["cycles"], float)
    a = np.asarray(table["a_m"], float)
    data = CrackData(str((specimen_info or {}).get("id", "1")), cycles, a)
    # E647 reduction works on crack-size readings; thin per-cycle tables to readings ≥ 0.25 mm apart
    keep = [0]
    for i in range(1, len(a)):
        if a[i] - a[keep[-1]] >= 0.25e-3:
            keep.append(i)
    thin = CrackData(data.specimen, cycles[keep], a[keep])
    rd = reduce(thin, setup, n=n)
    errs = force_errors(table, setup, band)
    marked = mark_force_band(rd, cycles[errs[0]], n) if errs is not None else 0
    write_reduced_csv(out / "reduced.csv", [rd], False)
    model: Model | None = None
    if rd.valid.any():  # a test that left the force band may have no valid point: reported, not fitted
        model = fit_rate(law, Points.from_reduced([rd], only_valid=True), setup.r_ratio, window_points=2 * n + 1)
    rms = model.fit["rms_log10_rate"] if model is not None else float("nan")
    a_n = plot_a_n(out / "a_n.png", [data], model=model, setup=setup)
    dadn = plot_dadn_dk(out / "dadn_dk.png", [rd], {f"{law} fit": model} if model is not None else None, setup.r_ratio, band=2 * rms)
    fb = None
    if "pmax_n" in table and "pmin_n" in table:
        fb = force_band(table["pmax_n"], table["pmin_n"], table.get("pmax_target_n", setup.pmax_n),
                        table.get("pmin_target_n", setup.pmax_n * setup.r_ratio), band)
    s = summary(rd)
    th = threshold(rd)
    spec_rows = [["geometry", setup.geometry.upper()], ["W [mm]", f"{setup.width_m * 1e3:.3f}"],
                 ["B [mm]", f"{setup.thickness_m * 1e3:.3f}"]] + [[k, v] for k, v in (specimen_info or {}).items()]
    load_rows = [["Pmax [kN]", f"{setup.pmax_n / 1e3:.4g}"], ["ΔP [kN]", f"{setup.delta_p_n / 1e3:.4g}"],
                 ["R", f"{setup.r_ratio:g}"]] + [[k, v] for k, v in (loading_info or {}).items()]
    b1 = [[i + 1, f"{rd.cycles[i]:.4g}", f"{rd.a_m[i] * 1e3:.3f}", f"{rd.a_fit_m[i] * 1e3:.3f}" if np.isfinite(rd.a_fit_m[i]) else "",
           f"{rd.dadn_m_per_cycle[i] * 1e3:.3e}" if np.isfinite(rd.dadn_m_per_cycle[i]) else "",
           f"{rd.delta_k_pa_sqrt_m[i] / 1e6:.3f}" if np.isfinite(rd.delta_k_pa_sqrt_m[i]) else "",
           "yes" if rd.valid[i] else rd.reasons[i]] for i in range(len(rd))]
    if model is not None:
        params = ", ".join(f"{k} = {v:.5g}" + (f" ± {model.se[k]:.2g}" if k in model.se else "") for k, v in model.params.items())
        fitted = (f"{params}; RMS log10 da/dN error {rms:.4f} over {model.fit['npoints']} valid points "
                  "(band in the plot: ±2 RMS).")
    else:
        fitted = "Not fitted: no valid reduced point."
    lines = [f"# {title}", "", "## Specimen", "", md_table(["quantity", "value"], spec_rows), "",
             "## Loading", "", md_table(["quantity", "value"], load_rows), ""]
    plots = [a_n, dadn]
    measured = crack not in (None, "model") and "a_law_m" in table
    if measured:
        law = np.asarray(table["a_law_m"], float)
        vs_law = plot_a_n_vs_law(out / "a_n_vs_law.png", cycles, a, law, str(crack))
        plots.insert(1, vs_law)
        i = int(np.flatnonzero(np.isfinite(a) & np.isfinite(law))[-1])
        grown, law_grown = a[i] - a[0], law[i] - law[0]
        lines += ["## Measured crack and the law", "",
                  f"The test ran on the crack measured by {str(crack).replace('_', ' ')} (ASTM E647); the spec's growth law's "
                  f"crack, integrated from the same measured forces, is beside it. At N = {cycles[i]:,.0f}: measured a = "
                  f"{a[i] * 1e3:.3f} mm, law a = {law[i] * 1e3:.3f} mm"
                  + (f" (the law's crack extension {100 * (law_grown / grown - 1):+.1f} % of the measured)" if grown > 0 else "") + ".", "",
                  f"![a-N measured and law]({vs_law.name})", ""]
        rows = [[f"{rd.cycles[k]:.6g}", f"{rd.a_m[k] * 1e3:.3f}", f"{np.interp(rd.cycles[k], cycles, law) * 1e3:.3f}"] for k in range(len(rd))]
        lines += [md_table(["N", "a measured [mm]", "a law [mm]"], rows[:: max(1, len(rows) // 25)]), ""]
    if "opening_force_n" in table:
        op = np.asarray(table["opening_force_n"], float)
        pm = np.asarray(table["pmax_n"], float) if "pmax_n" in table else setup.pmax_n
        dk_t = np.asarray(table["delta_k_pa_sqrt_m"], float) if "delta_k_pa_sqrt_m" in table else None
        dke_t = np.asarray(table["delta_k_eff_pa_sqrt_m"], float) if "delta_k_eff_pa_sqrt_m" in table else None
        from htm import core

        ev = np.asarray(table["events"]).astype(np.int64) if "events" in table else None
        lines += opening_section(cycles, op, pm, dk_t, dke_t,
                                 unresolved=int(((ev & core.EVENTS["closure_unresolved"]) != 0).sum()) if ev is not None else None)
    if errs is not None:
        w = errs[1]
        pct = f"±{w['band_pct']:g} %"
        if w["cycles_outside"] == 0:
            verdict = f"The force stayed inside the {pct} band on every cycle"
        else:
            verdict = (f"The force left the {pct} band on {w['cycles_outside']:,} of {w['cycles']:,} cycles; "
                       f"{marked} reduced point{'s' if marked != 1 else ''} over those cycles are marked invalid (force_band)")
        lines += [f"## Force control ({pct} band, ISO 12108)", "",
                  f"{verdict}: measured max |ΔF error| {w['max_abs_df_err_pct']:.3f} %, "
                  f"max |peak error| {w['max_abs_peak_err_pct']:.3f} %.", ""]
    if fb is not None:
        lines += [md_table(["cycles", f"fraction inside ±{100 * band:g} %", "max peak dev / ΔP", "max valley dev / ΔP", "RMS peak dev / ΔP"],
                           [[fb["cycles"], f"{100 * fb['fraction_inside']:.2f} %", f"{100 * fb['max_peak_dev_rel']:.3f} %",
                             f"{100 * fb['max_valley_dev_rel']:.3f} %", f"{100 * fb['rms_peak_dev_rel']:.3f} %"]]), ""]
    if variable_amplitude and "pmax_n" in table:
        lines += rainflow_section(table["pmax_n"], table["pmin_n"])
    lines += ["## Validity summary", "",
              f"{s['valid']} of {s['points']} reduced points valid; invalid: "
              + (", ".join(f"{k} ({v})" for k, v in sorted(s["reasons"].items())) or "none") + ". "
              + (f"ΔK_th (E647) = {th['delta_k_th_pa_sqrt_m'] / 1e6:.3g} MPa·√m." if th["reached"] else "ΔK_th not reached."), "",
              f"## Fitted law ({law})", "", fitted, "",
              "## Plots", "", f"![a-N]({a_n.name})", "", f"![da/dN-dK]({dadn.name})", "",
              "## Reduced data (E647 Table X1.2 / thesis Table B.1 layout)", "",
              md_table(["row", "N", "a [mm]", "â [mm]", "da/dN [mm/cycle]", "ΔK [MPa·√m]", "valid"], b1), ""]
    md = "\n".join(lines)
    md_path, html_path = write(out, md, title, plots)
    return {"markdown": md_path, "html": html_path, "reduced": out / "reduced.csv",
            "model": model, "force_band": fb, "force_errors": errs[1] if errs is not None else None, "validity": s}


def spec_test_report(out_dir: Path, spec, table: dict, title: str) -> str | None:
    """The test report (a–N, da/dN–ΔK, force band) of a test of `spec` (htm.spec.TestSpec) from its
    per-cycle table (engine columns), when it has enough crack growth: the path of report.md,
    "not written: why" when the E647 reduction refuses, None for a test it does not apply to."""
    from htm.errors import HtmError

    if not table or "cycle" not in table:
        return None
    test = (np.asarray(table["events"]).astype(np.uint32) & (1 | 128)) == 0
    if "judged" in table:  # the device loop's rows: not the ramp-in, nor a ramp back in after a hold
        test &= np.asarray(table["judged"], dtype=bool)
    elif "starting" in table:
        test &= ~np.asarray(table["starting"], dtype=bool)
    ph = spec.phases[-1]
    if spec.geometry not in ("ct", "mt") or test.sum() < 20 or ph.mode != "constant_force":
        return None
    pmax = ph.delta_f_n / (1 - ph.r_ratio) if ph.r_ratio >= 0 else ph.delta_f_n
    setup = Setup(spec.geometry, spec.width_m, spec.thickness_m, pmax, ph.r_ratio, spec.material["yield_strength_pa"])
    try:
        cols = {"cycles": "cycle", "a_m": "a_m", "pmax_n": "fmax_n", "pmin_n": "fmin_n", "df_err_pct": "df_err_pct",
                "peak_err_pct": "peak_err_pct"}
        if spec.variable_amplitude:  # each cycle judged against its own level
            cols.update(pmax_target_n="fmax_target_n", pmin_target_n="fmin_target_n")
        crack = spec.measurement.get("crack", "model")
        if crack != "model":  # the law's crack beside the measured one, the opening force and ΔK_eff
            cols.update(a_law_m="a_law_m", opening_force_n="opening_force_n", delta_k_pa_sqrt_m="delta_k_pa_sqrt_m",
                        delta_k_eff_pa_sqrt_m="delta_k_eff_pa_sqrt_m", events="events")
        write_test_report(out_dir, {k: np.asarray(table[c])[test] for k, c in cols.items() if c in table}, setup,
                          title=title, band=ph.tolerance, variable_amplitude=spec.variable_amplitude, crack=crack)
    except HtmError as e:  # too little growth for the E647 reduction: the test itself stands
        return f"not written: {e}"
    return str(Path(out_dir) / "report.md")
