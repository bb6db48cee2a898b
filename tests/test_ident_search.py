"""The search's rules that decide what is refitted and from where (unit level; the effect
matrix and the external benchmark show them at work on whole records)."""
import numpy as np

from htm.ident.model import Model, logf
from htm.ident.valve import MIN_GAIN_ERROR, _calibrated_off


def test_a_gain_within_calibration_tolerance_is_not_claimed():
    assert not _calibrated_off({"gain": 1.0 + 0.5 * MIN_GAIN_ERROR})
    assert _calibrated_off({"gain": 0.965})
    assert _calibrated_off({"gain": 1.15})


def test_a_parameter_pinned_where_it_started_stays_one_pinned_elsewhere_goes_to_nominal():
    # a spool started static (at its upper bound): still static is fine; pinned at its lower
    # bound it stood in for something else and restarts at its typical value
    nominal = {"valve_natural_hz": 150.0, "moving_mass_kg": 50.0}
    frees = [logf("valve_natural_hz", 0.4, 60.0), logf("moving_mass_kg", 0.4, 2.5)]
    start = np.array([np.log(60.0), 0.0])
    typical = np.zeros(2)
    static = Model(nominal, frees, np.array([np.log(60.0), 0.3]))
    assert np.allclose(static.unpinned(start, typical).x, [np.log(60.0), 0.3])
    slow = Model(nominal, frees, np.array([np.log(0.4), np.log(2.5)]))
    assert np.allclose(slow.unpinned(start, typical).x, [0.0, 0.0])
