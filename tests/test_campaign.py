"""Virtual test campaigns: the plan, the in-process run into the store, resuming, bad input."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from htm.campaign import engine
from htm.campaign import spec as campaign_spec
from htm.errors import SpecError
from htm.record.store import Store

ROOT = Path(__file__).resolve().parents[1]
BASE = ROOT / "examples" / "ct_constant_force.toml"


def campaign_file(tmp_path: Path, body: str, name: str = "small") -> Path:
    p = tmp_path / f"{name}.toml"
    p.write_text(f'[campaign]\nname = "{name}"\nbase = "{BASE}"\nchunk_tests = 2\nseed = 3\n' + body)
    return p


SMALL = """
[grid]
"loading.delta_f_n" = [3500.0, 4450.0]
[scatter]
samples = 3
"law.c" = { lognormal_sigma = 0.3 }
"""


def test_plan_is_grid_times_lhs_times_scatter_and_fixed_by_the_file(tmp_path):
    body = SMALL + '[lhs]\nsamples = 4\n"rig.overrides.supply_pressure_pa" = [17e6, 21e6]\n'
    c = campaign_spec.load(campaign_file(tmp_path, body))
    assert len(c) == 2 * 4 * 3
    assert c.swept == ["loading.delta_f_n", "rig.overrides.supply_pressure_pa"] and c.scattered == ["law.c"]
    # Latin hypercube: each of the 4 strata of the range holds exactly one point
    ps = sorted({i["rig.overrides.supply_pressure_pa"] for i in c.inputs})
    assert len(ps) == 4 and [int((p - 17e6) / 1e6) for p in ps] == [0, 1, 2, 3]
    assert c.docs[0]["rig"]["overrides"]["supply_pressure_pa"] == c.inputs[0]["rig.overrides.supply_pressure_pa"]
    assert len({i["law.c"] for i in c.inputs}) == len(c)  # every test its own material draw
    again = campaign_spec.load(campaign_file(tmp_path, body))
    assert again.id == c.id and again.inputs == c.inputs
    other = campaign_spec.load(campaign_file(tmp_path, body.replace("seed = 3", "seed = 4").replace("samples = 3", "samples = 2")))
    assert other.id != c.id


def test_in_process_campaign_writes_one_row_per_test_and_resumes(tmp_path):
    c = campaign_spec.load(campaign_file(tmp_path, SMALL))
    with Store(tmp_path / "store") as store:
        # stopped after the first chunk (as Ctrl-C would): what was written stays
        def interrupted(chunks, mode):
            yield from engine.local_runner(2)(chunks[:1], mode)
            raise KeyboardInterrupt

        with pytest.raises(KeyboardInterrupt):
            engine.run(c, store, interrupted, progress=False)
        assert engine.done(store, c) == {0, 1}
        s = engine.run(c, store, engine.local_runner(2), progress=False)
        assert (s["skipped"], s["ran"]) == (2, 4)
        rows = engine.table(store, c.id)
    assert [r["idx"] for r in rows] == list(range(6))
    lives = [r["life_cycles"] for r in rows]
    assert all(r["end_reason"] == "target_crack_length" and r["error"] is None for r in rows)
    # the larger force range and the larger Paris C shorten the life: physics, not bookkeeping
    low, high = rows[:3], rows[3:]
    assert min(r["life_cycles"] for r in low) > 0 and sum(r["life_cycles"] for r in low) > 1.5 * sum(r["life_cycles"] for r in high)
    by_c = sorted(low, key=lambda r: r["law.c"])
    assert [r["life_cycles"] for r in by_c] == sorted(lives[:3], reverse=True)
    assert all(0 <= r["max_abs_df_err_pct"] < 5 for r in rows)
    # the same result as running the test alone
    from htm import core
    from htm import spec as test_spec

    alone = core.run_test(test_spec.parse(c.docs[4], "x").config, c.mode)
    assert rows[4]["life_cycles"] == alone.cycles


def htm(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "htm.cli", *args], capture_output=True, text=True, timeout=120)


def one_line_error(r: subprocess.CompletedProcess, *words: str) -> None:
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    for w in words:
        assert w in lines[0], lines[0]


def test_bad_campaigns_fail_with_one_line_before_any_test(tmp_path):
    store = tmp_path / "store"
    bad_toml = tmp_path / "bad.toml"
    bad_toml.write_text('[campaign\nname = "x"\n')
    one_line_error(htm("campaign", str(bad_toml), "--store", str(store)), "not valid TOML")
    out_of_range = campaign_file(tmp_path, '[grid]\n"loading.r_ratio" = [0.1, 1.5]\n', "range")
    one_line_error(htm("campaign", str(out_of_range), "--store", str(store)), "loading.r_ratio", "1.5", "out of range")
    unknown_field = campaign_file(tmp_path, '[grid]\n"loading.delta_force" = [1.0]\n', "unknown")
    one_line_error(htm("campaign", str(unknown_field), "--store", str(store)), "delta_force")
    bad_rig = campaign_file(tmp_path, '[lhs]\nsamples = 2\n"rig.overrides.no_such_parameter" = [1.0, 2.0]\n', "rig")
    one_line_error(htm("campaign", str(bad_rig), "--store", str(store)), "no_such_parameter")
    # none of them got as far as the store
    assert not (store / "catalogue.sqlite").exists()
    with pytest.raises(SpecError, match="scatter"):
        campaign_spec.load(campaign_file(tmp_path, '[scatter]\nsamples = 2\n"law.c" = { uniform = 1 }\n', "scatter"))


def test_unreachable_scheduler_and_database_are_named(tmp_path):
    ok = campaign_file(tmp_path, SMALL)
    r = htm("campaign", str(ok), "--store", str(tmp_path / "store"), "--cluster", "tcp://127.0.0.1:9")
    one_line_error(r, "Dask scheduler", "tcp://127.0.0.1:9", "nothing was run")
    r = htm("campaign", str(ok), "--store", "postgresql://nobody@127.0.0.1:9/nothing")
    one_line_error(r, "postgresql://nobody@127.0.0.1:9/nothing", "cannot connect")
    # a password on the command line is refused, and not echoed
    r = htm("campaign", str(ok), "--store", "postgresql://nobody:s3cret@127.0.0.1:9/nothing")
    one_line_error(r, "PGPASSWORD")
    assert "s3cret" not in r.stderr + r.stdout


def test_a_campaign_killed_mid_run_resumes_without_repeating_or_losing_a_test(tmp_path):
    import os
    import re
    import signal
    import time

    p = campaign_file(tmp_path, SMALL.replace("samples = 3", "samples = 5"), "killed")  # 10 tests
    store = tmp_path / "store"
    cmd = [sys.executable, "-m", "htm.cli", "campaign", str(p), "--store", str(store), "--out", str(tmp_path / "out"), "--quiet", "--threads", "1"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    held = 0
    t0 = time.monotonic()
    while held < 2 and time.monotonic() - t0 < 60:
        time.sleep(0.1)
        if (store / "catalogue.sqlite").exists():
            with Store(store) as s:
                try:
                    held = s.db.execute("SELECT COUNT(*) FROM campaign_tests").fetchone()[0]
                except Exception:
                    held = 0
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=10)
    with Store(store) as s:
        kept = s.db.execute("SELECT COUNT(*) FROM campaign_tests").fetchone()[0]
    assert 2 <= kept < 10, kept  # killed mid-campaign, the finished chunks kept
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    m = re.search(r"10/10 tests in the store \((\d+) already there, (\d+) run now", r.stdout)
    assert m and int(m.group(1)) == kept and int(m.group(2)) == 10 - kept, r.stdout
    with Store(store) as s:
        idx = [i for (i,) in s.db.execute("SELECT idx FROM campaign_tests").fetchall()]
    assert sorted(idx) == list(range(10))
