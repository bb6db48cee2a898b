"""S-N, staircase and strain-life reports: the plots (curve, confidence and prediction bands,
run-outs marked) and the Markdown/HTML report beside fit.json (drawn with `htm.report`)."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from htm.fatigue.sn import SNData, SNFit
from htm.fatigue.staircase import Staircase
from htm.fatigue.strainlife import ENData, ENFit
from htm.report import md_table, pyplot, save, write


def plot_sn(path: Path, d: SNData, fit: SNFit, title: str = "") -> Path:
    """S-N diagram (MPa against cycles, log-log): failures, run-outs (open triangles with an
    arrow), the median curve, its 90 % confidence band and the 90 % prediction band."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.6, 4.6))
    lo, hi = d.stress_pa.min(), d.stress_pa.max()
    s = np.geomspace(lo * 0.97, hi * 1.03, 120)
    c_lo, c_hi = fit.confidence_band(s)
    p_lo, p_hi = fit.prediction_band(s)
    ax.fill_betweenx(s / 1e6, 10 ** p_lo, 10 ** p_hi, color="tab:blue", alpha=0.12, label="90 % prediction band (new specimen)")
    ax.plot(10 ** c_lo, s / 1e6, "--", color="tab:blue", lw=0.9, label="90 % confidence band (median)")
    ax.plot(10 ** c_hi, s / 1e6, "--", color="tab:blue", lw=0.9)
    ax.plot(10 ** fit.median_log10_n(s), s / 1e6, "-", color="k", lw=1.4, label=f"median ({fit.method})")
    f = ~d.runout
    ax.plot(d.cycles[f], d.stress_pa[f] / 1e6, "o", color="tab:red", ms=4, label=f"failures ({int(f.sum())})")
    if d.runout.any():
        ax.plot(d.cycles[d.runout], d.stress_pa[d.runout] / 1e6, ">", mfc="none", color="tab:green", ms=7,
                label=f"run-outs ({int(d.runout.sum())})")
    ax.set_xscale("log")
    ax.set_yscale("log")
    from matplotlib.ticker import FormatStrFormatter

    ax.yaxis.set_major_formatter(FormatStrFormatter("%g"))
    ax.yaxis.set_minor_formatter(FormatStrFormatter("%g"))
    ax.set_xlabel("cycles to failure N")
    ax.set_ylabel("stress amplitude S [MPa]")
    ax.set_title(title or f"S-N curve: {fit.n_specimens} specimens", fontsize=10)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7.5, loc="upper right")
    fig.tight_layout()
    return save(fig, path)


def _ci(v: tuple[float, float], fmt: str = "{:.4g}") -> str:
    return f"[{fmt.format(v[0])}, {fmt.format(v[1])}]"


def sn_summary_lines(fit: SNFit) -> list[str]:
    """The fit for a person: the curve with S in MPa, the intervals, the scatter, what it rests on."""
    a_mpa = fit.a + 6 * fit.b  # log10 N = a_mpa + b·log10(S / MPa)
    rows = [
        ("method", fit.method),
        ("specimens", f"{fit.n_specimens} ({fit.n_failures} failures, {fit.n_runouts} run-out(s) {fit.runouts_used})"),
        ("curve", f"log10 N = {fit.a:.4f} + ({fit.b:.4f})·log10 S[Pa]  =  {a_mpa:.4f} + ({fit.b:.4f})·log10 S[MPa]"),
        ("a, 90 % CI", f"{fit.a:.4f}  {_ci(fit.a_ci90)}"),
        ("b, 90 % CI", f"{fit.b:.4f}  {_ci(fit.b_ci90)}   (Basquin exponent k = {-fit.b:.3f})"),
        ("scatter σ(log10 N)", f"{fit.sigma_log10_n:.4f}  {_ci(fit.sigma_ci90)}   (life ratio N10/N90 = {10 ** (2 * 1.2816 * fit.sigma_log10_n):.2f})"),
    ]
    lin = fit.linearity
    if lin.get("applicable"):
        rows.append(("E739 linearity", f"F = {lin['F']:.3f} vs F_crit(95 %) = {lin['F_critical']:.3f}: "
                                       f"{'linear model not rejected' if lin['linear'] else 'LINEARITY REJECTED'}"))
    elif lin:
        rows.append(("E739 linearity", f"not applicable: {lin['reason']}"))
    w = max(len(k) for k, _ in rows)
    return [f"{k:<{w}}  {v}" for k, v in rows] + [f"note: {n}" for n in fit.notes]


def band_rows(fit: SNFit, stresses: np.ndarray) -> list[list[str]]:
    m = fit.median_log10_n(stresses)
    plo, phi = fit.prediction_band(stresses)
    return [[f"{s / 1e6:.1f}", f"{10 ** lo:,.0f}", f"{10 ** md:,.0f}", f"{10 ** hi:,.0f}"] for s, lo, md, hi in zip(stresses, plo, m, phi)]


def sn_report(out: Path, d: SNData, fit: SNFit, extra: dict[str, SNFit] | None = None) -> tuple[Path, Path]:
    img = plot_sn(out / "sn_curve.png", d, fit)
    levels = np.unique(d.stress_pa)[::-1]
    md = ["# S-N curve (ASTM E739 form)", "", f"Data: `{d.source}`.", "", "```", *sn_summary_lines(fit), "```", "",
          f"## Lives at the tested levels: median and 90 % prediction band for one new specimen "
          f"(rests on {fit.n_specimens} specimens)", "",
          md_table(["S [MPa]", "N lower 5 %", "N median", "N upper 95 %"], band_rows(fit, levels)), "",
          "![S-N curve](sn_curve.png)", ""]
    if extra:
        md += ["## The same data by other methods", "",
               md_table(["method", "b (k)", "a", "σ(log10 N)"],
                        [[k, f"{f.b:.4f} ({-f.b:.3f})", f"{f.a:.4f}", f"{f.sigma_log10_n:.4f}"] for k, f in extra.items()]), ""]
    return write(out, "\n".join(md), "S-N curve", [img])


def plot_staircase(path: Path, stress_pa: np.ndarray, runout: np.ndarray, st: Staircase) -> Path:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    i = np.arange(1, len(stress_pa) + 1)
    ax.plot(i, stress_pa / 1e6, "-", color="0.7", lw=0.8)
    ax.plot(i[~runout], stress_pa[~runout] / 1e6, "x", color="tab:red", ms=7, label="failure")
    ax.plot(i[runout], stress_pa[runout] / 1e6, "o", mfc="none", color="tab:green", ms=7, label="run-out")
    ax.axhline(st.strength_pa / 1e6, color="k", lw=1, label=f"fatigue strength {st.strength_pa / 1e6:.1f} MPa")
    ax.axhspan((st.strength_pa - st.sd_pa) / 1e6, (st.strength_pa + st.sd_pa) / 1e6, color="k", alpha=0.08, label="± 1 sd")
    ax.set_xlabel("specimen")
    ax.set_ylabel("stress amplitude [MPa]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7.5)
    fig.tight_layout()
    return save(fig, path)


def staircase_report(out: Path, source: str, stress_pa: np.ndarray, runout: np.ndarray, st: Staircase) -> tuple[Path, Path]:
    img = plot_staircase(out / "staircase.png", stress_pa, runout, st)
    md = ["# Staircase (ISO 12107, Dixon–Mood)", "", f"Data: `{source}`.", "", "```", *staircase_lines(st), "```", "",
          md_table(["S [MPa]", "failures", "run-outs"], [[f"{lv['stress_pa'] / 1e6:.2f}", lv["failures"], lv["runouts"]]
                                                          for lv in st.levels[::-1]]), "", "![staircase](staircase.png)", ""]
    return write(out, "\n".join(md), "Staircase", [img])


def staircase_lines(st: Staircase) -> list[str]:
    return [f"fatigue strength (50 %)  {st.strength_pa / 1e6:9.2f} MPa",
            f"standard deviation      {st.sd_pa / 1e6:9.2f} MPa   ({st.sd_rule}; ratio {st.ratio:.3f})",
            f"step                    {st.step_pa / 1e6:9.2f} MPa",
            f"specimens               {st.n_specimens:9d}       ({st.n_used} used; {st.event} counted)"]


def plot_en(path: Path, d: ENData, fit: ENFit) -> Path:
    plt = pyplot()
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(10.5, 4.3))
    f = ~d.runout
    n = np.geomspace(max(d.cycles.min() / 3, 1), d.cycles.max() * 3, 120)
    rev = 2 * n
    el = fit.sigma_f_pa / fit.modulus_pa * rev ** fit.basquin.q
    pl = fit.epsilon_f * rev ** fit.coffin.q
    ax.plot(n, el + pl, "k-", lw=1.4, label="total (fit)")
    ax.plot(n, el, "--", color="tab:blue", lw=0.9, label="elastic (Basquin)")
    ax.plot(n, pl, "--", color="tab:orange", lw=0.9, label="plastic (Coffin–Manson)")
    e = np.geomspace(d.strain_amplitude.min() * 0.95, d.strain_amplitude.max() * 1.05, 40)
    lo, _, hi = fit.prediction_band(e)
    ax.fill_betweenx(e, 10 ** lo, 10 ** hi, color="k", alpha=0.08, label="90 % prediction band (life)")
    ax.plot(d.cycles[f], d.strain_amplitude[f], "o", color="tab:red", ms=4, label="tests")
    if d.runout.any():
        ax.plot(d.cycles[d.runout], d.strain_amplitude[d.runout], ">", mfc="none", color="tab:green", ms=7, label="run-outs")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("cycles to failure N")
    ax.set_ylabel("strain amplitude [m/m]")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7.5)
    ep = np.geomspace(max(d.plastic[d.plastic > 0].min(), 1e-6) * 0.8, d.plastic.max() * 1.2, 80)
    sa = 10 ** fit.cyclic.p * ep ** fit.cyclic.q
    bx.plot(ep + sa / fit.modulus_pa, sa / 1e6, "k-", lw=1.2, label="cyclic curve σa = K'·εpa^n' (+ σa/E)")
    bx.plot(d.strain_amplitude, d.stress_pa / 1e6, "o", color="tab:red", ms=4, label="stabilised loops")
    bx.set_xlabel("strain amplitude [m/m]")
    bx.set_ylabel("stress amplitude [MPa]")
    bx.grid(alpha=0.3)
    bx.legend(fontsize=7.5)
    fig.tight_layout()
    return save(fig, path)


def en_lines(fit: ENFit) -> list[str]:
    j: dict[str, Any] = fit.to_json()
    return [f"σ'f  {j['sigma_f_pa'] / 1e6:10.1f} MPa   90 % CI [{j['sigma_f_pa_ci90'][0] / 1e6:.1f}, {j['sigma_f_pa_ci90'][1] / 1e6:.1f}]",
            f"b    {j['b']:10.4f}       90 % CI [{j['b_ci90'][0]:.4f}, {j['b_ci90'][1]:.4f}]",
            f"ε'f  {j['epsilon_f']:10.4f}       90 % CI [{j['epsilon_f_ci90'][0]:.4f}, {j['epsilon_f_ci90'][1]:.4f}]",
            f"c    {j['c']:10.4f}       90 % CI [{j['c_ci90'][0]:.4f}, {j['c_ci90'][1]:.4f}]",
            f"K'   {j['K_prime_pa'] / 1e6:10.1f} MPa   90 % CI [{j['K_prime_pa_ci90'][0] / 1e6:.1f}, {j['K_prime_pa_ci90'][1] / 1e6:.1f}]",
            f"n'   {j['n_prime']:10.4f}       90 % CI [{j['n_prime_ci90'][0]:.4f}, {j['n_prime_ci90'][1]:.4f}]   (b/c = {j['n_prime_from_b_over_c']:.4f})",
            f"E    {fit.modulus_pa / 1e9:10.1f} GPa   transition life 2Nt = {j['transition_reversals']:,.0f} reversals",
            f"life scatter σ(log10 N) = {fit.life_sigma_log10:.4f}; {fit.n_specimens} specimens "
            f"({fit.n_plastic} with plastic strain)"]


def en_report(out: Path, d: ENData, fit: ENFit) -> tuple[Path, Path]:
    img = plot_en(out / "strain_life.png", d, fit)
    strains = np.unique(d.strain_amplitude)[::-1]
    lo, med, hi = fit.prediction_band(strains)
    rows = [[f"{e:.5f}", f"{10 ** a:,.0f}", f"{10 ** m:,.0f}", f"{10 ** b:,.0f}"] for e, a, m, b in zip(strains, lo, med, hi)]
    md = ["# Strain-life and cyclic stress–strain curve (ASTM E606 / ISO 12106)", "", f"Data: `{d.source}`.", "",
          "```", *en_lines(fit), "```", "",
          f"## Lives: median and 90 % prediction band for one new specimen (rests on {fit.n_specimens} specimens)", "",
          md_table(["strain amplitude", "N lower 5 %", "N median", "N upper 95 %"], rows), "",
          "![strain-life](strain_life.png)", ""]
    return write(out, "\n".join(md), "Strain-life", [img])
