"""Variable-amplitude loading ([variable_amplitude]: blocks, or a spectrum file of peaks and
valleys) in the simulator and on the virtual rig: every cycle runs at its own level with the
peak-valley compensation learning per cycle, the crack grows by each level's ΔK, the report
counts the measured history with rainflow; bad input is one clear line."""
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest

from htm import core
from htm.cli import main
from htm.control import Session
from htm.control.session import specimen_of
from htm.devices.config import virtual_config
from htm.errors import SpecError
from htm.record.store import Store
from htm.run import run_test
from htm.spec import load, parse

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "ct_constant_force.toml"
BLOCKS = [[50, 4450.0, 0.1], [20, 5340.0, 0.1], [30, 3000.0, 0.3]]
EV_START_STOP = core.EVENTS["start"] | core.EVENTS["stop"]


def _doc(rate_hz: float = 1000.0, cycles: int = 300) -> dict:
    d = tomllib.loads(EXAMPLE.read_text())
    d.pop("run")
    d["loading"]["control_rate_hz"] = rate_hz
    d["end"]["max_cycles"] = cycles
    d["law"]["c"] *= 20.0  # growth visible per level over a few hundred cycles
    return d


def _level_targets(blocks, n):
    """(Fmax, Fmin) of cycles 1..n for blocks repeated in turn."""
    seq = []
    while len(seq) < n:
        for cycles, df, r in blocks:
            fmax = df / (1 - r)
            seq += [(fmax, r * fmax)] * cycles
    return np.array(seq[:n])


def _spectrum_file(tmp_path: Path, n: int = 120) -> tuple[Path, np.ndarray]:
    rng = np.random.default_rng(7)
    pv = np.round(np.column_stack([rng.uniform(3500.0, 6000.0, n), rng.uniform(300.0, 1500.0, n)]), 1)
    f = tmp_path / "spectrum.txt"
    f.write_text("# measured service history, N\n" + "\n".join(f"{p:.1f}\n{v:.1f}" for p, v in pv) + "\n")
    return f, pv


def _judged(t):
    return (np.asarray(t["events"]) & EV_START_STOP) == 0


def test_blocks_in_simulation_follow_each_level_inside_the_band():
    d = _doc()
    d["variable_amplitude"] = {"blocks": BLOCKS}
    spec = parse(d)
    assert spec.mode == "full" and spec.variable_amplitude
    o = run_test(spec)
    t = o.table
    c = _judged(t)
    cyc = np.asarray(t["cycle"])[c]
    want = _level_targets(BLOCKS, int(cyc[-1]))[cyc - 1]
    assert np.allclose(t["fmax_target_n"][c], want[:, 0]) and np.allclose(t["fmin_target_n"][c], want[:, 1])
    rng_t = want[:, 0] - want[:, 1]
    assert np.abs(t["fmax_n"][c] - want[:, 0]).max() / rng_t.min() < 0.02
    assert np.abs(t["fmin_n"][c] - want[:, 1]).max() / rng_t.min() < 0.02
    # the crack grows by each level's ΔK (Paris m = 3): the overload block grows it (5340/4450)³ faster
    dadn = np.asarray(t["dadn_m_per_cycle"])[c]
    lvl = np.round(rng_t).astype(int)
    ratio = np.median(dadn[lvl == 5340]) / np.median(dadn[lvl == 4450])
    assert ratio == pytest.approx((5340 / 4450) ** 3, rel=0.03)
    # each block's convergence, logged once (first pass), from its own first cycle
    conv = o.convergence
    assert [(e["cause"], e["first_cycle"]) for e in conv] == [("start", 26), ("level", 51), ("level", 71)]
    assert all(e["cycles_to_2pct"] == 0 for e in conv) and conv[1]["cycles_seen"] == 20
    with pytest.raises(SpecError, match="run.mode must be"):
        parse({**d, "run": {"mode": "jump"}})


def test_spectrum_file_in_simulation_and_report_counts_it_with_rainflow(tmp_path, capsys):
    f, pv = _spectrum_file(tmp_path)
    d = _doc(cycles=2000)
    d["law"]["c"] *= 100.0  # ≈ 5 mm of growth: enough readings for the E647 reduction of the report
    d["variable_amplitude"] = {"spectrum_file": f.name}
    spec_path = tmp_path / "va.toml"
    from htm.spec import dumps
    spec_path.write_text(dumps(d))
    spec = load(spec_path)  # the file is found beside the spec
    assert len(spec.spectrum) == len(pv)
    o = run_test(spec)
    t = o.table
    c = _judged(t)
    cyc = np.asarray(t["cycle"])[c]
    want = pv[(cyc - 1) % len(pv)]
    assert np.array_equal(t["fmax_target_n"][c], want[:, 0]) and np.array_equal(t["fmin_target_n"][c], want[:, 1])
    # a new random level every cycle: the compensation learned on one cycle serves the next, so
    # the peaks stay inside ±2 % and the range within ±3 % (95 % of cycles inside ±2 %)
    pe, de = np.abs(t["peak_err_pct"][c]), np.abs(t["df_err_pct"][c])
    assert pe.max() < 2.0, pe.max()
    assert de.max() < 3.0 and (de < 2.0).mean() > 0.95, (de.max(), (de < 2.0).mean())
    # htm run: the report counts the measured history with rainflow
    out = tmp_path / "o"
    assert main(["run", str(spec_path), "--out", str(out), "--quiet"]) == 0
    md = (out / "report.md").read_text()
    assert "rainflow count (ASTM E1049)" in md and "±2 % band" in md
    counted = np.array(core.rainflow(np.column_stack([t["fmax_n"][c], t["fmin_n"][c]]).ravel().tolist()))
    assert counted[:, 2].sum() == pytest.approx(c.sum(), abs=1.0), "one rainflow cycle per applied cycle"
    capsys.readouterr()


def test_a_killed_spectrum_test_resumes_from_the_store_alone(tmp_path):
    """The store keeps the spectrum inline: a test killed mid-run resumes from another folder
    after its spectrum file is gone, and every cycle still runs its own level."""
    from htm.spec import dumps
    f, pv = _spectrum_file(tmp_path)
    d = _doc(cycles=60_000)
    d["law"]["c"] /= 20.0
    d["variable_amplitude"] = {"spectrum_file": f.name}
    spec_path = tmp_path / "va.toml"
    spec_path.write_text(dumps(d))
    store = tmp_path / "store"
    htm = [sys.executable, "-m", "htm.cli"]
    opts = ["--store", str(store), "--quiet", "--no-recording"]
    proc = subprocess.Popen(htm + ["run", str(spec_path), "--out", str(tmp_path / "o")] + opts,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while proc.poll() is None and time.monotonic() < deadline and not any(
            p.stat().st_size > 50_000 for p in store.glob("tests/*/journal-000.htmj")):
        time.sleep(0.02)
    assert proc.poll() is None, "the test ended before it could be killed; make it longer"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    with Store(store) as s:
        tid = s.list_tests()[0]["id"]
        kept = tomllib.loads(s.get(tid)["spec"])["variable_amplitude"]
    assert "spectrum_file" not in kept and np.array_equal(np.array(kept["spectrum"]), pv)
    f.unlink()
    r = subprocess.run(htm + ["resume", tid] + opts, cwd=tmp_path.parent, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    with Store(store) as s:
        t, table = s.get(tid), s.cycles(tid)
    assert t["status"] == "finished" and any(e["kind"] == "resumed" for e in t["events"])
    c = np.asarray(table["cycle"])
    assert np.array_equal(c, np.arange(1, len(c) + 1)) and len(c) >= 60_000, "no gap, no duplicate, run to the end"
    j = _judged(table)
    want = pv[(c[j] - 1) % len(pv)]
    assert np.array_equal(table["fmax_target_n"][j], want[:, 0]), "each cycle at its own level after the resume"


@pytest.mark.parametrize("va,needle", [
    ({"spectrum": [[5000.0, 6000.0]]}, r"spectrum\[0\]: peak 5000 N must exceed its valley"),
    ({"spectrum": []}, "non-empty list of \\[peak_n, valley_n\\]"),
    ({"spectrum": [[5000.0, "x"]]}, r"spectrum\[0\].valley_n = 'x' must be a number"),
    ({"spectrum": [[5000.0, 500.0]], "blocks": [[10, 4450.0, 0.1]]}, "one of them"),
])
def test_a_malformed_inline_spectrum_is_one_clear_line(va, needle):
    d = _doc()
    d["variable_amplitude"] = va
    with pytest.raises(SpecError, match=needle):
        parse(d)


@pytest.mark.parametrize("text,needle", [
    ("5000\n500\n4000\n", "even number"),
    ("5000, 500\n4000\n", "mixes one-column"),
    ("5000, 6000\n", "must exceed its valley"),
    ("5000, abc\n", "not one or two numbers"),
    ("# nothing\n", "no forces"),
])
def test_a_malformed_spectrum_file_is_one_clear_line(tmp_path, capsys, text, needle):
    f = tmp_path / "bad.txt"
    f.write_text(text)
    d = _doc()
    d["variable_amplitude"] = {"spectrum_file": str(f)}
    with pytest.raises(SpecError, match=needle):
        parse(d)
    from htm.spec import dumps
    p = tmp_path / "bad.toml"
    p.write_text(dumps(d))
    assert main(["run", str(p), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert needle in err and "Traceback" not in err
    d["variable_amplitude"] = {"blocks": [[10, 4450.0, 1.5]]}
    with pytest.raises(SpecError, match="r_ratio"):
        parse(d)
    d["variable_amplitude"] = {"blocks": [[10, 90e3, 0.1]]}
    with pytest.raises(SpecError, match=r"variable_amplitude\.blocks\[0\]\.delta_f_n = 90000 .*K_IC"):
        parse(d)


def test_blocks_and_spectrum_on_the_virtual_rig_match_the_simulator(tmp_path):
    """The device loop in lock-step runs the same sequence through the same cycle machine: each
    cycle's level, and its measured peak and valley within the sensors' noise of the simulator's."""
    f, pv = _spectrum_file(tmp_path, 40)
    for va in ({"blocks": BLOCKS}, {"spectrum_file": str(f)}):
        d = _doc(rate_hz=500.0, cycles=160)
        d["variable_amplitude"] = va
        spec = parse(d)
        sim = run_test(spec, "full").table
        c = _judged(sim)
        s = Session().open(virtual_config("lockstep", 500.0), virtual=True, specimen=specimen_of(spec), thread=False)
        try:
            s.start(spec, f0_n=0.0, record=False)
            s.step(50 * 170)
            rows = [r for r in s.cycles_since(0) if not r["starting"]]
            assert not [e for e in s.events_since(0) if e["kind"] == "trip"]
        finally:
            s.close()
        rig = {k: np.array([r[k] for r in rows]) for k in ("cycle", "fmax_n", "fmin_n", "fmax_target_n", "fmin_target_n")}
        assert np.array_equal(rig["cycle"], np.asarray(sim["cycle"])[c])
        assert np.array_equal(rig["fmax_target_n"], sim["fmax_target_n"][c]) and np.array_equal(rig["fmin_target_n"], sim["fmin_target_n"][c])
        span = rig["fmax_target_n"] - rig["fmin_target_n"]
        for k in ("fmax_n", "fmin_n"):
            assert (np.abs(rig[k] - sim[k][c]) / span).max() < 0.005, (va, k)
        assert (np.abs(rig["fmax_n"] - rig["fmax_target_n"]) / rig["fmax_target_n"]).max() < 0.02, va
