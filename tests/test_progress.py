"""The one progress line of long commands (`htm run`, `htm campaign`, `htm life-band`): toward
the end condition with rate and time left, drawn complete at the end; plain lines (no carriage
returns, no escape codes) when stderr is not a terminal."""
import io
from pathlib import Path

from htm import cli
from htm.terminal import Progress

SPEC = Path(__file__).resolve().parents[1] / "examples" / "ct_constant_force.toml"


class Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_htm_run_off_a_terminal_writes_plain_lines_ending_at_the_end_condition(tmp_path, capsys):
    assert cli.main(["run", str(SPEC), "--out", str(tmp_path / "o"), "--store", str(tmp_path / "s"), "--no-recording"]) == 0
    err = capsys.readouterr().err
    assert "\r" not in err and "\x1b" not in err
    lines = [ln for ln in err.splitlines() if ln.startswith("ct_constant_force")]
    assert lines, err
    last = lines[-1]
    # the end condition reached: the crack at a/W 0.600 of 0.600, 100 %, with the end reason and rate
    assert "100.0 %" in last and "target_crack_length" in last
    assert "cycles/s" in last and "95," in last
    assert any("a/W" in ln and " of 0.600" in ln for ln in lines), lines


def test_on_a_terminal_one_line_redrawn_never_wider_than_the_terminal(monkeypatch):
    monkeypatch.setenv("COLUMNS", "60")
    out = Tty()
    p = Progress(None, "cycles", "ct", stream=out, interval_s=0)
    for i in range(1, 6):
        p.update(i * 1000, i / 10, detail="a 15.29 mm, a/W 0.301 of 0.600, a long detail that cannot fit")
    p.close("target_crack_length", fraction=1.0)
    text = out.getvalue()
    draws = text.split("\r")[1:]
    assert len(draws) == 6 and text.endswith("\n") and text.count("\n") == 1
    for d in draws:
        visible = d.replace("\x1b[K", "").rstrip("\n")
        assert len(visible) <= 59, visible
    assert "100.0 %" in draws[-1] and "[####################]" in draws[-1]
    assert "left" in draws[-2]  # a time left once the pace is known


def test_time_left_follows_the_recent_pace(monkeypatch):
    """A crack speeds up as it grows: the time left comes from the recent pace, not the average."""
    clock = [0.0]
    monkeypatch.setattr("htm.terminal.time.perf_counter", lambda: clock[0])
    out = io.StringIO()
    p = Progress(None, "cycles", "t", stream=out, interval_s=0)
    # 30 % in the first 60 s, then 10 % per 5 s
    for t, f in ((0, 0.0), (30, 0.15), (60, 0.3), (65, 0.4), (70, 0.5)):
        clock[0] = float(t)
        p.update(int(f * 1e5), f)
    last = out.getvalue().splitlines()[-1]
    # recent pace: 0.2 per 10 s → 0.5 left in 25 s (the average pace would say 70 s)
    assert "25 s left" in last, last
