"""The envelope that long lines are drawn from (htm.report.envelope): what a plot of a 60 s record
shows must be what the full line shows — every extreme kept, in time order, each column's range;
and the plotting library loaded in the background while a diagnosis computes (preload)."""
import subprocess
import sys

import numpy as np

from htm.report import envelope


def test_a_long_line_keeps_every_column_s_extremes_in_order():
    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 60.0, 30_000)
    y = rng.normal(size=t.size)
    y[12_345] = 40.0  # one spike between two samples' worth of pixels
    y[20_001] = -35.0
    tx, yx = envelope(t, y, columns=1000)
    assert len(yx) == 2000 and np.all(np.diff(tx) >= 0)
    assert 40.0 in yx and -35.0 in yx
    edges = np.linspace(0, t.size, 1001).astype(int)
    for a, b in zip(edges[:-1:97], edges[1::97]):  # every column's range is the line's range there
        inside = (tx >= t[a]) & (tx <= t[b - 1])
        assert yx[inside].min() == y[a:b].min() and yx[inside].max() == y[a:b].max()


def test_a_short_line_is_drawn_as_it_is():
    t, y = np.arange(100.0), np.sin(np.arange(100.0))
    tx, yx = envelope(t, y, columns=1000)
    assert np.array_equal(tx, t) and np.array_equal(yx, y)


def test_preload_imports_the_plotting_library_in_the_background_once():
    # a fresh interpreter: matplotlib is not loaded until preload() loads it on its own thread,
    # and a second call starts no second thread
    code = ("import sys, htm.report as r\n"
            "assert 'matplotlib.pyplot' not in sys.modules\n"
            "r.preload(); r.preload()\n"
            "assert len(r._PRELOAD) == 1 and r._PRELOAD[0].name == 'htm-preload-matplotlib'\n"
            "r._PRELOAD[0].join(60)\n"
            "assert 'matplotlib.pyplot' in sys.modules\n"
            "import matplotlib; assert matplotlib.get_backend().lower() == 'agg'\n"
            "print('ok')\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"
