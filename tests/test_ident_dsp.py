"""htm.ident.dsp computes what scipy's filters and spectrum compute for the diagnosis's arguments,
and a whole diagnosis loads no scipy (its import cost a second of CPU per `htm diagnose`)."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from scipy.ndimage import maximum_filter1d, median_filter, minimum_filter1d
from scipy.signal import lfilter, welch

from htm.ident import dsp


@pytest.mark.parametrize("n", [1, 255, 256, 257, 4097, 30000])
def test_filters_equal_scipy(n):
    z = np.random.default_rng(n).normal(size=n).cumsum()
    for a in (0.0, 0.3, np.exp(-0.5), np.exp(-0.1), np.exp(-0.02), 0.99999):
        ref = lfilter([1.0 - a], [1.0, -a], z)
        assert np.max(np.abs(dsp.first_order_lag(z, a) - ref)) <= 1e-12 * np.max(np.abs(ref))
    for w in (1, 3, 51, 1251):
        h = w // 2
        for ours, theirs in ((dsp.running_max, maximum_filter1d), (dsp.running_min, minimum_filter1d)):
            if n > 2 * h:  # the ends are cut short here; the diagnosis pads them itself
                assert np.array_equal(ours(z, w)[h:n - h], theirs(z, w)[h:n - h])
        if w < 100:
            assert np.array_equal(dsp.running_median(z, w), median_filter(z, size=w, mode="nearest"))


@pytest.mark.parametrize("nperseg", [256, 2047, 2048, 30000])
def test_welch_equals_scipy(nperseg):
    x = np.random.default_rng(nperseg).normal(size=30000) + np.sin(np.arange(30000) * 0.3)
    f0, p0 = welch(x - x.mean(), fs=500.0, nperseg=nperseg)
    f1, p1 = dsp.welch(x - x.mean(), 500.0, nperseg)
    assert np.array_equal(f0, f1)
    assert np.max(np.abs(p1 - p0)) <= 1e-12 * np.max(p0)
    assert np.argmax(p1) == np.argmax(p0)


def test_a_diagnosis_loads_no_scipy():
    """A record with a supply switch (the supply's running median and envelope) and a force outside
    the vocabulary (the model's own floor with its first-order lags, then the probes with the
    residuals' spectra): no scipy module is imported along the way."""
    probe = ("import sys\n"
             "from htm.ident import proving, sim\n"
             "from htm.ident.diagnose import diagnose\n"
             "rec, _ = proving.make_record({}, seed=9, duration_s=10.0, effect_outside_table='friction_bump')\n"
             "assert sim.supply_schedule(rec) is not None\n"
             "r = diagnose(rec)\n"
             "print(sorted({t['stage'] for t in r['trace']} & {'verdict', 'probes'}), r['unexplained'],\n"
             "      sorted({m.split('.')[0] for m in sys.modules if m.startswith('scipy')}))\n")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "['probes', 'verdict'] True []"
