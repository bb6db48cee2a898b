"""`htm run SPEC --out DIR`: a whole fatigue crack growth test in the Rust core, with a progress
bar, the per-cycle table (Parquet), summary.json, a text summary and the test report; recorded
into the test store and a rerun recording as it runs (resumable after a crash: `htm resume ID`)."""
from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from htm import core
from htm.errors import HtmError
from htm.record import web
from htm.spec import TestSpec, load, parse, stored_text
from htm.terminal import Progress, add_json_flag, emit_json, path


def run_spec(spec: TestSpec, mode: str | None = None, progress: bool = False) -> tuple[core.Outcome, float]:
    """Run `spec` in `mode` (default: the spec's); returns (the engine's outcome, wall seconds)."""
    prog = core.Progress()
    box: dict[str, Any] = {}

    def work() -> None:
        try:
            box["out"] = core.run_test(spec.config, mode or spec.mode, prog)
        except BaseException as e:  # re-raised in the caller's thread
            box["err"] = e

    t0 = time.perf_counter()
    th = threading.Thread(target=work, daemon=True)
    th.start()
    bar = progress_line(spec, 0) if progress else None
    while True:
        th.join(0.2)
        if not th.is_alive():
            break
        if bar:
            bar.update(prog.cycles, *_cycle_fraction(spec, prog.cycles))
    wall = time.perf_counter() - t0
    if bar:
        out = box.get("out")
        if out:
            f, where = _crack_fraction(spec, int(out.cycles), float(out.a_end_m))
            bar.close(f"{out.end_reason}: {where}", f, int(out.cycles))
        else:
            bar.close("failed")
    if "err" in box:
        raise box["err"]
    return box["out"], wall


def run_test(spec: TestSpec | str | Path, mode: str | None = None, *, progress: bool = False) -> core.Outcome:
    """Run a whole fatigue crack growth test on the simulated rig (plant, controller, specimen,
    crack growth in the Rust core), without recording it into the store.

    Parameters
    ----------
    spec : TestSpec or str or Path
        The test, or the path of its TOML spec.
    mode : str, optional
        ``"full"`` (every cycle through the plant) or ``"jump"`` (cycle-jump); default the spec's.
    progress : bool
        Draw a progress bar on stderr.

    Returns
    -------
    Outcome
        ``end_reason``, ``cycles``, final crack size ``a_end_m`` [m] and the per-cycle table
        ``table`` (an Arrow record batch, ``pyarrow.record_batch(out.table)``; ``out.table["a_m"]``
        one column; SI columns: ``a_m`` [m], ``delta_k_pa_sqrt_m`` [Pa·√m], measured peaks and
        valleys [N], errors [%], ``events``).
    """
    if not isinstance(spec, TestSpec):
        spec = load(spec)
    out, _ = run_spec(spec, mode, progress)
    return out


# first line of a stored spec run on a twin (`--model`): the model's path, for `htm resume`
TWIN_TAG = "# htm twin: "
# raw high-rate windows of a simulated test: the core's policy (the first cycles, a few from each
# decade, a few around each event)
RAW_POLICY = core.RAW_POLICY
# wall time of one engine chunk [s]: the journal gets a block of rows (and a snapshot) this often
CHUNK_S = 0.25


def drive(sess: core.TestRun, writer: Any, spec: TestSpec | None, progress: bool) -> tuple[dict[str, Any], float]:
    """Advance `sess` (a `core.TestRun`) chunk by chunk into `writer` (a `TestWriter`) to the
    end; returns (the run's summary, wall seconds). A recording error stops the test safely
    (the journal keeps what was written, `htm resume` continues)."""
    from htm.errors import RecordError

    t0 = time.perf_counter()
    engine_s = 0.0
    bar = progress_line(spec, sess.cycle) if progress and spec is not None else None
    try:
        while not sess.finished:
            te = time.perf_counter()
            chunk = sess.advance(max_seconds=CHUNK_S)
            engine_s += time.perf_counter() - te
            # the chunk's tables are Arrow record batches: the writer takes their columns as they are
            writer.cycles(core.columns(chunk.table), core.columns(chunk.raw) if len(chunk.raw) else None,
                          None if chunk.end_reason else bytes(sess.snapshot()))
            if bar:
                bar.update(sess.cycle, *_crack_fraction(spec, sess.cycle, sess.a_m))
    except RecordError as e:
        if bar:
            bar.close("recording failed")
        writer.interrupt("recording_failed", str(e))
        raise RecordError(f"{e} — test stopped safely at cycle {writer.last_cycle:,}; what was recorded is kept "
                          f"(`htm resume {writer.id}` continues once the cause is fixed)") from None
    except KeyboardInterrupt:
        if bar:
            bar.close("interrupted")
        writer.interrupt("interrupted", "by the operator")
        raise HtmError(f"interrupted at cycle {writer.last_cycle:,}; `htm resume {writer.id}` continues") from None
    wall = time.perf_counter() - t0
    outcome = sess.outcome()
    if bar:
        f, where = _crack_fraction(spec, sess.cycle, sess.a_m)
        bar.close(f"{outcome.end_reason}: {where}" if outcome else None, f, sess.cycle)
    return _result(outcome, engine_wall_s=engine_s), wall


def _result(o: core.Outcome | None, **extra: Any) -> dict[str, Any]:
    """A finished run's summary values by name (the record's result, with `extra`)."""
    assert o is not None, "the run has finished"
    return {"end_reason": o.end_reason, "cycles": o.cycles, "a_end_m": o.a_end_m, "max_abs_df_err_pct": o.max_abs_df_err_pct,
            "max_abs_peak_err_pct": o.max_abs_peak_err_pct, "cycles_simulated": o.cycles_simulated,
            "size_criterion_cycle": o.size_criterion_cycle, "velocity_gain_m_s_per_v": o.velocity_gain_m_s_per_v,
            "demod_gains": o.demod_gains, "convergence": o.convergence, "worst_first_cycles_df_pct": o.worst_first_cycles_df_pct,
            **extra}


def run_recorded(spec: TestSpec, spec_text: str, mode: str, store: Any, progress: bool = False, *,
                 recording: bool = True, spawn: bool = False, connect: str | None = None) -> tuple[str, dict[str, Any], float]:
    """Run `spec` into `store` (+ its rerun recording); returns (test id, result with the whole
    per-cycle table, wall seconds)."""
    from htm.record.writer import TestWriter

    # a bad spec failed in `parse` (its TestConfig), before anything is recorded
    writer = TestWriter.create(store, spec.name, "simulated", mode, "toml", spec_text, spec.frequency_hz,
                               recording=recording, spawn=spawn, connect=connect)
    try:
        sess = core.TestRun(spec.config, mode, RAW_POLICY)
    except HtmError as e:
        writer.close("failed", "engine_error", {"error": str(e)})
        raise
    return _finish(writer, sess, spec, mode, progress)


def _finish(writer: Any, sess: Any, spec: TestSpec, mode: str, progress: bool) -> tuple[str, dict[str, Any], float]:
    try:
        out, wall = drive(sess, writer, spec, progress)
    except HtmError as e:
        if not writer.journal.closed:  # an engine error: the test failed, its rows stay
            writer.close("failed", "engine_error", {"error": str(e)})
        raise
    s = summary(spec, out, wall, mode)
    s.pop("wall_time_s")
    tc = time.perf_counter()
    from htm.record import convergence

    convergence.log(writer, out["convergence"], spec.frequency_hz)
    writer.close("finished", out["end_reason"], s)
    out = dict(out, close_wall_s=time.perf_counter() - tc)
    out["table"] = writer.store.cycles(writer.id)
    return writer.id, out, wall


def resume_recorded(store: Any, test_id: str, progress: bool = False, *, recording: bool = True, spawn: bool = False,
                    connect: str | None = None) -> tuple[str, TestSpec, str, dict[str, Any], float]:
    """Continue a simulated test of `store` from its journal's last engine snapshot; returns
    (test id, spec, mode, result with the whole table, wall seconds of this session)."""
    import tomllib

    from htm.errors import RecordError
    from htm.record import journal
    from htm.record.writer import TestWriter

    row = store.get(test_id)
    if row["kind"] != "simulated":
        raise RecordError(f"test {test_id} is a {row['kind']} test; only simulated tests resume with `htm resume`")
    twin = row["spec"].startswith(TWIN_TAG)
    spec = parse(tomllib.loads(row["spec"]), row["name"], check=not twin)  # a twin's run was checked on the twin
    if twin:  # run on an identified model's twin: resumed on it
        from htm.twin import on_model

        spec = on_model(spec, row["spec"].splitlines()[0][len(TWIN_TAG):], check=False)
    mode = row["mode"]
    writer, segs = TestWriter.reopen(store, test_id, recording=recording, spawn=spawn, connect=connect)
    records = [r for s in segs for r in s.records]
    chunks = [r for r in records if r.kind == journal.CHUNK]
    closed = [r for r in records if r.kind == journal.CLOSE]
    if closed or (chunks and not chunks[-1].blob and len(chunks[-1].arrays.get("events", []))
                  and int(chunks[-1].arrays["events"][-1]) & core.EVENTS["end"]):
        # the run had ended (its last rows are in): only the closing was cut short
        m = closed[-1].meta if closed else {}
        writer.event("resumed", "closing a test that had ended")
        writer.close(m.get("status", "finished"), m.get("end_reason", row["end_reason"]), m.get("results", {}))
        out = {"end_reason": row["end_reason"], "table": store.cycles(test_id)}
        return test_id, spec, mode, out, 0.0
    snaps = [r for r in chunks if r.blob]
    try:
        cfg = spec.config
        sess = core.TestRun.restore(cfg, mode, snaps[-1].blob) if snaps else core.TestRun(cfg, mode, RAW_POLICY)
    except HtmError as e:
        writer.interrupt("resume_failed", str(e))
        raise RecordError(f"test {test_id}: {e}") from None
    writer.event("resumed", f"from cycle {sess.cycle:,} (a = {sess.a_m * 1e3:.3f} mm)", sess.cycle, sess.cycle / spec.frequency_hz)
    tid, out, wall = _finish(writer, sess, spec, mode, progress)
    return tid, spec, mode, out, wall


def progress_line(spec: TestSpec, start_cycle: int) -> Progress:
    """The progress line of a test: toward its end crack size (a/W) or its cycle limit."""
    return Progress(None, "cycles", spec.name, start=start_cycle)


def _a_over_w(spec: TestSpec, a_m: float) -> float:
    """a/W as the spec states it (M(T): a is the half crack, a/W of the half width)."""
    return a_m * (1.0 if spec.geometry == "ct" else 2.0) / spec.width_m


def _crack_fraction(spec: TestSpec, cycles: int, a_m: float) -> tuple[float, str]:
    """(fraction of the way to the end condition, what to show): the crack's way from a0 to the
    end size or the cycles' way to max_cycles, whichever is further."""
    a_end = spec.phases[-1].end_a_m
    fa = (a_m - spec.a0_m) / (a_end - spec.a0_m) if a_end > spec.a0_m else 0.0
    f = max(fa, cycles / spec.end["max_cycles"])
    return f, f"a {a_m * 1e3:.2f} mm, a/W {_a_over_w(spec, a_m):.3f} of {_a_over_w(spec, a_end):.3f}"


def _cycle_fraction(spec: TestSpec, cycles: int) -> tuple[float | None, str]:
    """Without the crack size (a run outside the store reports only cycles): the cycle limit's
    share, when the spec sets one (the default limit says nothing about when the test ends)."""
    limit = spec.end["max_cycles"]
    if limit >= core.TEST_DEFAULTS["max_cycles"]:
        return None, f"until a/W {_a_over_w(spec, spec.phases[-1].end_a_m):.3f}"
    return cycles / limit, f"of at most {limit:,}"


def summary(spec: TestSpec, out: core.Outcome | dict[str, Any], wall: float, mode: str) -> dict[str, Any]:
    """summary.json's values; `out` the engine's outcome or a recorded run's result (`drive`)."""
    from htm.record import convergence

    if isinstance(out, core.Outcome):
        out = _result(out)
    return {
        "spec": spec.name, "mode": mode, "cycles": int(out["cycles"]), "end_reason": out["end_reason"],
        "final_a_m": float(out["a_end_m"]), "final_a_over_w": _a_over_w(spec, float(out["a_end_m"])),
        "max_abs_df_err_pct": float(out["max_abs_df_err_pct"]), "max_abs_peak_err_pct": float(out["max_abs_peak_err_pct"]),
        "wall_time_s": wall, "cycles_simulated": int(out["cycles_simulated"]),
        "size_criterion_cycle": out["size_criterion_cycle"], "velocity_gain_m_s_per_v": out["velocity_gain_m_s_per_v"],
        "demod_gains": out.get("demod_gains"), **convergence.results(out.get("convergence", [])),
        **force_verdict(spec, out),
        # which plant the test ran on: the spec's nominal rig, or an identified model's twin
        "model": spec.twin,
    }


def force_verdict(spec: TestSpec, out: dict[str, Any]) -> dict[str, Any]:
    """Whether the test held its force band (the test phase's tolerance), and what the
    feasibility check said before it ran: a test forced past its limits says so."""
    tol_pct = 100 * spec.phases[-1].tolerance
    worst = max(float(out["max_abs_df_err_pct"]), float(out["max_abs_peak_err_pct"]))
    return {"force_tolerance_pct": tol_pct, "force_in_band": bool(worst <= tol_pct),
            "feasibility": spec.feasibility().verdict(), "override_limits": spec.override_limits}


def write_outputs(out_dir: Path, spec: TestSpec, out: core.Outcome | dict[str, Any], wall: float, mode: str) -> dict[str, Any]:
    """summary.json, cycles.parquet, summary.txt and the report of a run (`out`: the engine's
    outcome, or a recorded run's result with the store's table)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    out_dir.mkdir(parents=True, exist_ok=True)
    s = summary(spec, out, wall, mode)
    # the engine's table is an Arrow record batch, the store's a dict of columns: each is written
    # whole, column by column
    if isinstance(out, core.Outcome):
        batch = pa.record_batch(out.table)
        pq.write_table(pa.Table.from_batches([batch]), out_dir / "cycles.parquet")
        table = core.columns(out.table)
    else:
        table = out["table"]
        pq.write_table(pa.table({k: np.asarray(v) for k, v in table.items()}), out_dir / "cycles.parquet")
    m = measured_crack(spec, table)
    if m is not None:
        s["measurement"] = m
        m["plot"] = crack_vs_law_plot(out_dir / "crack_vs_law.png", spec, table).name
    (out_dir / "summary.json").write_text(json.dumps(s, indent=2, default=float))
    text = summary_text(spec, s)
    (out_dir / "summary.txt").write_text(text + "\n")
    from htm.fatigue.report import spec_test_report

    title = f"Simulated test {spec.name}" + (f" on the twin {spec.twin['path']}" if spec.twin else "")
    s["report"] = spec_test_report(out_dir, spec, table, title)
    return s


def measured_crack(spec: TestSpec, table: dict[str, Any]) -> dict[str, Any] | None:
    """How the crack the test ran on (measured: compliance or potential drop) compares with the
    law's prediction beside it, from the per-cycle table; None for a test on the law's crack."""
    crack = spec.measurement.get("crack", "model")
    if crack == "model" or "a_law_m" not in table or not len(table["a_m"]):
        return None
    a, law = np.asarray(table["a_m"], dtype=float), np.asarray(table["a_law_m"], dtype=float)
    ev = np.asarray(table["events"]).astype(np.uint32)
    ok = np.isfinite(a) & np.isfinite(law)
    if not ok.any():
        return None
    i = int(np.flatnonzero(ok)[-1])
    grown, law_grown = a[i] - spec.a0_m, law[i] - spec.a0_m
    op = np.asarray(table.get("opening_force_n", np.full(len(a), np.nan)), dtype=float)
    dk, dke = (np.asarray(table.get(c, np.full(len(a), np.nan)), dtype=float) for c in ("delta_k_pa_sqrt_m", "delta_k_eff_pa_sqrt_m"))
    ratio = dke / np.where(dk > 0, dk, np.nan)
    fin = np.isfinite(op)
    return {"crack": crack, "readings": int(((ev & core.EVENTS["reading"]) != 0).sum()),
            "failed_readings": int(((ev & core.EVENTS["reading_failed"]) != 0).sum()),
            "a_end_m": float(a[i]), "a_law_end_m": float(law[i]), "at_cycle": int(np.asarray(table["cycle"])[i]),
            # the law's crack extension over the measured one, minus 1: how far the material departs
            # from the law the spec assumed
            "law_extension_error_pct": float(100 * (law_grown / grown - 1)) if grown > 0 else None,
            "opening_force_n": [float(op[fin].min()), float(op[fin].max())] if fin.any() else None,
            "delta_k_eff_ratio": [float(np.nanmin(ratio)), float(np.nanmax(ratio))] if np.isfinite(ratio).any() else None}


def crack_vs_law_plot(path: Path, spec: TestSpec, table: dict[str, Any]) -> Path:
    """a–N of the crack the test ran on (measured) and the law's crack beside it."""
    from htm.report import pyplot, save

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4))
    n = np.asarray(table["cycle"], dtype=float)
    ax.plot(n, 1e3 * np.asarray(table["a_m"], dtype=float), label=f"measured ({spec.measurement['crack'].replace('_', ' ')})")
    ax.plot(n, 1e3 * np.asarray(table["a_law_m"], dtype=float), "--", label="the spec's law")
    ax.set_xlabel("cycles N")
    ax.set_ylabel("crack size a [mm]")
    ax.set_title(f"{spec.name}: measured crack and the law's prediction")
    ax.grid(alpha=0.3)
    ax.legend()
    return save(fig, path)


def summary_text(spec: TestSpec, s: dict[str, Any]) -> str:
    from htm.record import convergence

    rows = [
        ("test", f"{spec.name}: {spec.geometry.upper()} W = {spec.width_m * 1e3:.1f} mm, B = {spec.thickness_m * 1e3:.2f} mm, "
                 f"{spec.waveform} {spec.frequency_hz:g} Hz, {spec.controller['type']} control, mode {s['mode']}"),
        ("end", f"{s['end_reason']} after {s['cycles']:,} cycles"),
        ("crack", f"a = {spec.a0_m * 1e3:.2f} → {s['final_a_m'] * 1e3:.2f} mm (a/W {s['final_a_over_w']:.3f})"),
        ("force error", f"max |ΔF| {s['max_abs_df_err_pct']:.3f} %, max |peak| {s['max_abs_peak_err_pct']:.3f} %: "
                        f"{'inside' if s['force_in_band'] else 'OUTSIDE'} the ISO 12108 band ±{s['force_tolerance_pct']:g} %"),
        *((("measured crack", _measured_text(s["measurement"])),) if s.get("measurement") else ()),
        ("rig model", _twin_label(spec)),
        ("rig limits", s["feasibility"] + (" (run anyway: override_limits)" if s["override_limits"] else "")),
        *(("convergence", convergence.describe(e)) for e in s.get("convergence", [])),
        ("size criterion", "met throughout" if s["size_criterion_cycle"] is None else f"violated from cycle {s['size_criterion_cycle']:,}"),
        ("wall time", f"{s['wall_time_s']:.2f} s ({s['cycles'] / max(s['wall_time_s'], 1e-9):,.0f} cycles/s, "
                      f"{s['cycles_simulated']:,} cycles through the plant)"),
    ]
    w = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{w}}  {v}" for k, v in rows)


def _measured_text(m: dict[str, Any]) -> str:
    text = (f"{m['crack'].replace('_', ' ')}, {m['readings']:,} readings; at cycle {m['at_cycle']:,} measured "
            f"{m['a_end_m'] * 1e3:.2f} mm, the law's {m['a_law_end_m'] * 1e3:.2f} mm")
    if m["law_extension_error_pct"] is not None:
        text += f" (law's extension {m['law_extension_error_pct']:+.1f} %)"
    if m["opening_force_n"]:
        text += f"; opening force {m['opening_force_n'][0] / 1e3:.2f}–{m['opening_force_n'][1] / 1e3:.2f} kN"
    return text + f"; plot {m['plot']}"


def _twin_label(spec: TestSpec) -> str:
    from htm.twin import label

    return label(spec.twin)


def load_spec(args: argparse.Namespace, check: bool = True) -> TestSpec:
    """The spec of `htm run`, on the twin of `--model` when given (ModelError: one line, exit 2)."""
    if not getattr(args, "model", None):
        return load(args.spec, check=check)
    from htm.twin import on_model

    return on_model(load(args.spec, check=False), args.model, check=check)


def cmd_check(args: argparse.Namespace) -> int:
    """`htm run --check SPEC`: every feasibility check; exit 1 when the rig cannot run it."""
    spec = load_spec(args, check=False)
    feas = spec.feasibility()
    if args.json:
        from dataclasses import asdict

        emit_json({"spec": spec.name, "feasible": feas.feasible, "verdict": feas.verdict(), "model": spec.twin,
                   "override_limits": spec.override_limits, "checks": [asdict(c) for c in feas.checks]})
        return 0 if feas.feasible else 1
    print(f"{spec.name}: can the rig run this test? ({_twin_label(spec)})")
    print(feas.table())
    if not feas.feasible and spec.override_limits:
        print("[run] override_limits = true: `htm run` runs it anyway and reports the force error it reaches")
    return 0 if feas.feasible else 1


def cmd_run(args: argparse.Namespace) -> int:
    from htm.fatigue import lifetest

    if lifetest.is_life_file(args.spec):  # force_life / strain_life: the life engine
        if args.check or args.no_store:
            return lifetest.cmd_run(args.spec, args.out, args.json, args.check)
        from htm import lifestore
        from htm.record.store import Store

        with Store(args.store) as st:
            return lifetest.cmd_run(args.spec, args.out, args.json, store=lambda sp, res, wall: lifestore.record(
                st, args.spec, sp, res, wall, recording=not args.no_recording))
    if args.check:
        return cmd_check(args)
    if not args.out:
        raise HtmError("--out DIR is required (or --check to check the spec only)")
    spec = load_spec(args)  # refuses a test the rig (or its twin) cannot run (InfeasibleTest)
    for c in spec.feasibility().checks:
        if c.status != "ok":
            forced = " (override_limits: running anyway)" if c.status == "refused" else ""
            print(f"htm run: warning: {c.name}: {c.text}{forced}", file=sys.stderr)
    mode = args.mode or spec.mode
    out_dir = Path(args.out)
    if (out_dir / "summary.json").exists():
        raise HtmError(f"{out_dir} already holds a test (summary.json); choose another --out")
    writable(out_dir)  # before the test runs: a test must not end "finished" with nowhere to write
    if args.no_store:
        out, wall = run_spec(spec, mode, progress=not args.quiet)
        s = write_outputs(out_dir, spec, out, wall, mode)
    else:
        from htm.record.store import Store

        with Store(args.store) as store:
            text = stored_text(args.spec, spec)
            if spec.twin:  # a resume runs on the same twin
                text = f"{TWIN_TAG}{Path(spec.twin['path']).resolve()}\n" + text
            test_id, out, wall = run_recorded(spec, text, mode, store, progress=not args.quiet,
                                              recording=not args.no_recording, spawn=args.spawn, connect=args.connect)
            if not args.json:
                print(f"store: test {test_id} in {path(store.root)}"
                      + ("" if args.no_recording else f" (recording {path(store.test_dir(test_id) / 'recording.rrd')})"))
            s = write_outputs(out_dir, spec, out, wall, mode)
            # the outputs a person reads, referenced from the catalogue (Results, `htm db show`)
            store.add_file(test_id, "summary", out_dir / "summary.json")
            if s["report"] and not s["report"].startswith("not"):
                store.add_file(test_id, "report", Path(s["report"]))
    if args.json:
        emit_json(dict(s, test_id=None if args.no_store else test_id, out=str(out_dir)))
        return 0
    print(summary_text(spec, s))
    report = f", {Path(s['report']).name}" if s["report"] and not s["report"].startswith("not") else ""
    print(f"outputs: {path(out_dir)}/summary.json, cycles.parquet, summary.txt{report}")
    return 0


def cmd_resume(args: argparse.Namespace) -> int:
    from htm.record.store import Store

    with Store(args.store) as store:
        test_id, spec, mode, out, wall = resume_recorded(store, args.id, progress=not args.quiet, recording=not args.no_recording,
                                                         spawn=args.spawn, connect=args.connect)
        t = store.get(test_id)
    s = write_outputs(Path(args.out), spec, out, wall, mode) if args.out and "cycles" in out else None
    if args.json:
        emit_json({"test_id": test_id, "status": t["status"], "end_reason": t["end_reason"], "cycles": t["cycles"],
                   "summary": s})
        return 0
    print(f"test {test_id}: {t['status']}, {t['end_reason']} after {t['cycles']:,} cycles")
    if s is not None:
        print(summary_text(spec, s))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="run a fatigue crack growth test spec (TOML) on the simulated rig",
                       description="Run a whole fatigue crack growth test (plant, controller, specimen, crack growth) "
                                   "in the Rust core; write DIR/summary.json, DIR/cycles.parquet, a text summary and a report.")
    p.add_argument("spec", help="test spec (TOML), e.g. examples/ct_constant_force.toml")
    p.add_argument("--out", help="output directory (must not already hold a test); required unless --check")
    p.add_argument("--check", action="store_true",
                   help="only check whether the rig can run the test (force, valve flow, frequency, stroke, E647 size "
                        "criterion) and print the largest feasible ΔF and frequency; exit 1 if it cannot")
    p.add_argument("--mode", choices=["full", "jump"], help="full fidelity or cycle-jump (default: the spec's [run] mode)")
    p.add_argument("--model", metavar="MODEL.json",
                   help="run (or --check) on the twin: an identified rig model (`htm rig identify` / `htm diagnose`'s "
                        "model.json, its base parameters and every finding) instead of the spec's nominal rig")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    add_json_flag(p)
    add_store_args(p)
    p.add_argument("--no-store", action="store_true", help="do not record into the store (no journal, no resume, no recording)")
    p.set_defaults(func=web.serving(cmd_run))

    r = sub.add_parser("resume", help="continue a simulated test after a crash or a stop",
                       description="Continue a test from its journal: the engine state of the last block written "
                                   "(cycle count, crack length, controller, waveform), into the same store and recording.")
    r.add_argument("id")
    r.add_argument("--out", help="also write summary.json, cycles.parquet and the report here")
    r.add_argument("--quiet", action="store_true", help="no progress line")
    add_json_flag(r)
    add_store_args(r)
    r.set_defaults(func=web.serving(cmd_resume))


def writable(out_dir: Path) -> None:
    """Create `out_dir` and check a file can be written in it (raises HtmError naming it)."""
    import tempfile

    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out_dir):
            pass
    except OSError as e:
        raise HtmError(f"--out {out_dir}: cannot write there ({e.strerror or e}); nothing was run") from None


def add_store_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--store", help="test store folder (default $HTM_STORE or ~/.local/share/htm/store)")
    p.add_argument("--no-recording", action="store_true", help="no rerun recording (the store still keeps every cycle)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--spawn", action="store_true", help="also stream to a rerun viewer started now")
    g.add_argument("--connect", metavar="URL", help="also stream to a running rerun viewer (e.g. rerun+http://127.0.0.1:9876/proxy)")
    g.add_argument("--serve-web", nargs="?", type=int, const=web.DEFAULT_PORT, metavar="PORT",
                   help=f"also serve the live test to rerun's web viewer: the page on PORT (default {web.DEFAULT_PORT}), "
                        "the stream on PORT+1, every interface; after the test it keeps serving until Ctrl-C")
