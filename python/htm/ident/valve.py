"""The valve-level model family: records with a valve command `u`, modelled by the core's plant
(servo-valve, chambers, cylinder, friction, specimen) behind the record's sensors. Its base model
(EFFECTS.md) with the free parameters a real rig needs, and its candidate effects."""
from __future__ import annotations

from typing import Any, Callable

import numpy as np

from htm.core import Params
from htm.ident import features as ft
from htm.ident import sim
from htm.ident.dsp import welch
from htm.ident.family import Family
from htm.ident.model import Candidate, Derived, Free, Model, derive, get_value, has_key, lin, logf
from htm.ident.records import Record
from htm.ident.settings import DEFAULT, SearchSettings

# Claim thresholds of this family's effects: `settings.SearchSettings` (min_asymmetry,
# min_gain_error, min_null_bias, min_leakage, min_sag, min_valve_lag: unit and reason there); these names are its defaults.
MIN_ASYMMETRY = DEFAULT.min_asymmetry
MIN_GAIN_ERROR = DEFAULT.min_gain_error
MIN_NULL_BIAS = DEFAULT.min_null_bias
MIN_LEAKAGE = DEFAULT.min_leakage
MIN_VALVE_LAG = DEFAULT.min_valve_lag
MIN_SAG = DEFAULT.min_sag
# Base-model parameters stated by the metadata (nominal; bounds say how far a rig may be off).
RIG_FREES = [
    logf("moving_mass_kg", 0.4, 2.5, prior=0.3),
    logf("valve_rated_flow_m3_s", 0.4, 2.5, prior=0.3),
    logf("bulk_modulus_pa", 0.4, 2.5, prior=0.3),
    logf("dead_volume_a_m3", 0.3, 3.0, step=0.05, prior=0.5),
    logf("dead_volume_b_m3", 0.3, 3.0, step=0.05, prior=0.5),
    logf("supply_pressure_pa", 0.5, 1.5, step=0.01, prior=0.1),
    logf("specimen_stiffness_n_m", 0.33, 3.0, step=0.02, prior=0.3),
]
# What the metadata does not state, with bounds from the physics of real rigs: friction, the
# valve's underlap, laminar transition and spool (a second-order system of 60 Hz and up: far above the
# sample rate it is a static valve), the return
# line's back-pressure and the oil's stiffening with pressure. Wide priors keep the parameters
# the record cannot tell near their typical values.
OTHER_FREES = [
    logf("friction_viscous_n_s_m", 0.02, 20.0, step=0.05, prior=1.0),
    logf("friction_coulomb_n", 0.02, 20.0, step=0.05, prior=1.0),
    logf("friction_static_n", 0.2, 4.0, step=0.1, prior=0.5),
    logf("friction_stribeck_m_s", 0.2, 5.0, step=0.1, prior=1.0),
    logf("friction_smoothing_m_s", 0.05, 10.0, step=0.1, prior=1.0),
    lin("valve_underlap_v", 0.1, 0.0, 5.0, step=0.1, prior=1.0),
    logf("valve_transition_dp_pa", 0.03, 10.0, step=0.1, prior=1.0),
    logf("valve_natural_hz", 0.4, 60.0, step=0.05, prior=1.0),
    logf("valve_damping", 0.5, 1.6, step=0.05, prior=0.3),
    lin("tank_pressure_pa", 1e5, 0.0, 10.0, step=0.1),
    lin("bulk_modulus_slope", 1.0, 0.0, 20.0, step=0.5, prior=10.0),
]
# Typical values of what the metadata leaves out (a servo-valve's spool).
SPOOL_HZ, SPOOL_DAMPING = 150.0, 0.7
# Held while the gross parameters are first fitted (search's first stage): the details of a real
# rig; the spool meanwhile starts as fast as its bound allows (a static valve).
DETAILS = frozenset({"friction_stribeck_m_s", "friction_smoothing_m_s", "valve_transition_dp_pa", "valve_natural_hz",
                     "valve_damping", "tank_pressure_pa", "bulk_modulus_slope"})




def _set_coulomb(p: Any, value: float) -> None:
    p["friction_coulomb_pos_n"] = value
    p["friction_coulomb_neg_n"] = value


def _set_coulomb_diff(p: Any, value: float) -> None:
    c = p["friction_coulomb_pos_n"]
    p["friction_coulomb_pos_n"] = max(0.0, c + value)
    p["friction_coulomb_neg_n"] = max(0.0, c - value)


# The base model's Coulomb friction is symmetric (one level for both directions);
# friction_asymmetry splits it (pos = C + d, neg = C - d).
_COULOMB_PAIR = ("friction_coulomb_pos_n", "friction_coulomb_neg_n")
derive(Derived("friction_coulomb_n", lambda p: 0.5 * (p["friction_coulomb_pos_n"] + p["friction_coulomb_neg_n"]),
               _set_coulomb, _COULOMB_PAIR))
derive(Derived("friction_coulomb_diff_n", lambda p: 0.5 * (p["friction_coulomb_pos_n"] - p["friction_coulomb_neg_n"]),
               _set_coulomb_diff, _COULOMB_PAIR))


# The share of its own mass below which the weighed coordinate does not move a vertical rig's mass.
WEIGHED_MASS_FLOOR = 0.2


def _set_coulomb_diff_weighed(p: Any, value: float) -> None:
    """The asymmetry d with the weight it trades with held: in motion the pair adds d to the
    friction force whichever the direction (sign(v) (C + d sign(v)) = C sign(v) + d), as a weight
    d/g would on a vertical rig; the mass's own coordinate then stands for the force in motion
    (m g + d), and d moves only the split that the inertia and the holds set."""
    _set_coulomb_diff(p, value)
    g = p["gravity_m_s2"]
    if g > 0:
        m = p["moving_mass_kg"]
        p["moving_mass_kg"] = max(m - value / g, WEIGHED_MASS_FLOOR * m)


def _weight_held(p: Any) -> bool:
    """The weighed coordinate holds at `p`: its setter left the mass above the floor (from a mass
    m, m - d/g while d/g < (1 - floor) m; at the floor, d/g >= (1 - floor)/floor times the mass
    that is left). At the floor the weight it trades with is no longer held."""
    g = p["gravity_m_s2"]
    return g <= 0 or get_value(p, "friction_coulomb_diff_n") / g < (1.0 - WEIGHED_MASS_FLOOR) / WEIGHED_MASS_FLOOR * p["moving_mass_kg"]


# A vertical rig's asymmetry, separable from gravity (`_set_coulomb_diff_weighed`): the free the
# friction_asymmetry candidate moves. Without gravity it is the plain asymmetry.
derive(Derived("friction_coulomb_diff_weighed_n", lambda p: 0.5 * (p["friction_coulomb_pos_n"] - p["friction_coulomb_neg_n"]),
               _set_coulomb_diff_weighed, (*_COULOMB_PAIR, "moving_mass_kg")))


class ValveFamily(Family):
    """The valve-level plant for one record: nominal parameters, free parameters, candidates and
    the simulator options (a switched supply, the open-loop horizon)."""

    name = "valve"
    vocabulary = sim.EFFECT_IDS
    has_probes = True

    def __init__(self, rec: Record, channels: list[str], horizon_s: float | None = None,
                 settings: SearchSettings = DEFAULT) -> None:
        self.settings = settings
        self.rec = rec
        self.channels = channels
        self._shown: dict[str, np.ndarray] = {}  # the candidates' `shows` masks, by effect
        if {"p_a", "p_b"} <= set(channels):  # the chamber pressures: two transducers measuring alike
            self.siblings = {"p_a": "p_b", "p_b": "p_a"}
        nominal = sim.params_from_meta(rec.meta)
        if "p_s" in channels:  # a measured supply starts the fit at what the gauge reads at rest
            nominal["supply_pressure_pa"] = float(np.nanpercentile(rec.columns["p_s"], 90))
        rig = rec.meta.get("rig") or {}
        nominal["valve_natural_hz"] = float(rig.get("valve_natural_hz") or SPOOL_HZ)
        nominal["valve_damping"] = float(rig.get("valve_damping") or SPOOL_DAMPING)
        self.nominal = nominal
        self.base_frees: list[Free] = [f for f in RIG_FREES + OTHER_FREES if has_key(nominal, f.key) and
                                       (not f.log or get_value(nominal, f.key) > 0)]
        self.rig_keys = {f.key for f in RIG_FREES}
        self.first_stage = DETAILS
        self.opts: dict[str, Any] = {"supply": sim.supply_schedule(rec)}  # once: a switched supply the model follows
        if horizon_s is not None:
            self.opts["horizon_s"] = horizon_s

    def slowest_spool_lag(self) -> float:
        """The longest low-frequency lag [s] the base model's own spool can make: a declared spool's
        2*zeta/omega_n; an undeclared one may be as slow as its bound (60 Hz: servo-valve spools
        run at 60-200 Hz and up) at the typical damping, and a first-order lag shorter than that
        is a spool the record does not state, fitted as a lag (a 2.3 ms lag in place of a true
        100 Hz spool while the fit sends its spool to 1 kHz)."""
        rig = self.rec.meta.get("rig") or {}
        if rig.get("valve_natural_hz"):
            return spool_lag(self.nominal)
        p = dict(valve_natural_hz=_spool_lo() * SPOOL_HZ, valve_damping=float(rig.get("valve_damping") or SPOOL_DAMPING))
        return spool_lag(p)

    def low_pressure(self) -> np.ndarray:
        """The samples where entrained air stands apart from a bulk modulus or dead volumes set
        wrong: where a measured chamber's absolute pressure is at or below its median over
        sqrt(signature_contrast) — free air's compliance (~1/p^2) there at least that many times
        its typical share. No sample at all where the chambers' pressures are not measured.
        Computed once (asked at every judge of the candidate)."""
        if "air" in self._shown:
            return self._shown["air"]
        cols = self.rec.columns
        n = len(cols["t"])
        mask = np.zeros(n, dtype=bool)
        p_atm = float(self.nominal["atmospheric_pressure_pa"])
        for c in ("p_a", "p_b"):
            if c not in self.channels:
                continue
            p = np.asarray(cols[c], dtype=float) + p_atm
            ok = np.isfinite(p)
            if ok.any():
                mask |= ok & (p <= float(np.median(p[ok])) / np.sqrt(self.settings.signature_contrast))
        self._shown["air"] = mask
        return mask

    def leak_flow_share(self) -> np.ndarray:
        """The samples where an internal leak stands apart from the base's dynamics: where its
        flow, proportional to the measured load pressure |p_a - p_b|, is at least
        signature_contrast times its typical (median) share of the actuator's flow A |v| (slow
        motion under load; |v| floored at the velocity reading's noise). Both chamber pressures
        must be measured (else no test: `shows` is None). Computed once."""
        if "leak" in self._shown:
            return self._shown["leak"]
        cols = self.rec.columns
        dp = np.abs(np.asarray(cols["p_a"], dtype=float) - np.asarray(cols["p_b"], dtype=float))
        v, floor = self._velocity()
        ok = np.isfinite(v) & np.isfinite(dp)
        share = np.where(ok, dp / (np.abs(np.where(ok, v, 0.0)) + floor), 0.0)
        typical = float(np.median(share[ok])) if ok.any() else 0.0
        self._shown["leak"] = ok & (share >= self.settings.signature_contrast * typical) & (share > 0)
        return self._shown["leak"]

    def standstill(self) -> np.ndarray:
        """The samples where the actuator stands still: |v| within twice the velocity reading's
        noise floor (v differenced from y where no velocity is read). Computed once."""
        if "still" in self._shown:
            return self._shown["still"]
        v, floor = self._velocity()
        ok = np.isfinite(v)
        self._shown["still"] = ok & (np.abs(np.where(ok, v, np.inf)) <= 2.0 * floor)
        return self._shown["still"]

    def _velocity(self) -> tuple[np.ndarray, float]:
        """The record's velocity (read, or differenced from y) and its noise floor."""
        cols = self.rec.columns
        if "v" in self.channels:
            v = np.asarray(cols["v"], dtype=float)
            return v, ft.noise_floor(v, ft.declared_resolution(self.rec.meta, "v"))
        v = np.gradient(np.asarray(cols["y"], dtype=float), np.asarray(cols["t"], dtype=float))
        return v, ft.noise_floor(v)

    def start(self, base: Model) -> np.ndarray:
        """Coordinates the fit starts from: the nominal values, the spool as fast as its bound
        allows (a static valve until the second stage frees it)."""
        x = base.start()
        for i, f in enumerate(base.frees):
            if f.key == "valve_natural_hz":
                x[i] = f.hi
        return x

    @property
    def closed_loop(self) -> bool:
        """Sensor noise acts inside the loop (a declared controller the model re-simulates)."""
        return sim.closed_loop(self.rec)

    @property
    def has_command(self) -> bool:
        return "u" in self.rec.columns and bool(np.isfinite(self.rec.columns["u"]).any())

    @staticmethod
    def effect_fields(effect: str, channel: str | None = None) -> dict[str, str]:
        return sim.effect_fields(effect, channel)

    @staticmethod
    def simulate(plist: list[Params], rec: Record, **opts: Any) -> list[dict[str, np.ndarray]]:
        return sim.predict(plist, rec, **opts)

    def candidates(self, scales: dict[str, float], rate_hz: float) -> list[Candidate]:
        """Every effect the core can switch on for this record (sensor effects on its channels)."""
        p, rec, channels = self.nominal, self.rec, self.channels
        out: list[Candidate] = []
        dt = 1.0 / rate_hz
        ctrl = (rec.meta.get("controller") or {}).get("type")
        st = self.settings
        cand = self.candidate
        # a leak is judged where its flow stands apart only when both chambers' pressures are read
        leak_shows = st.signature_contrast > 0 and st.shows_ratio > 0 and {"p_a", "p_b"} <= set(channels)

        for c in channels:
            offset = self.sensor_candidate("sensor_offset", c, scales[c], claimable=_not_a_tolerated_gain(rec, c, st.min_gain_error))
            gain = self.sensor_candidate("sensor_gain", c, 0.01, claimable=_calibrated_off(st.min_gain_error))
            delay = self.sensor_candidate("sensor_delay", c, dt, claimable=_share_of("delay_s", st.min_sensor_delay * dt)
                                          if st.min_sensor_delay > 0 else None, form=spool_slowed_by)
            # The loop regulates what its own sensor reads: an offset or gain of that sensor only
            # moves the true state, which nothing else measures — unless a specimen ties position
            # and force: its zero-force position is trusted, so the force's offset shows against
            # the position and the position's in the force; a gain of the force only trades with
            # the identified stiffness, unless the chamber pressures weigh the true force.
            if (c, ctrl) == ("y", "position_pff") and "f" not in channels:
                out.append(delay)
            elif (c, ctrl) == ("f", "force_p") and not {"p_a", "p_b"} <= set(channels):
                out += [offset, delay]
            else:
                out += [offset, gain, delay]
        # A band of the command narrower than the command's own noise is dithered through: it
        # has no signature of its own (a closed loop's command carries its sensor's noise).
        u_noise = ft.noise_floor(np.asarray(self.rec.columns["u"], dtype=float)) if "u" in self.rec.columns else 0.0

        def wider_than_noise(q: dict[str, float]) -> bool:
            return q["half_width_v"] >= u_noise

        def wider_than_null(q: dict[str, float]) -> bool:
            return wider_than_noise(q) and q["half_width_v"] >= st.min_null_bias * p["valve_max_command_v"]

        out += [
            cand("valve_null_bias", None, (lin("valve_null_bias_v", 0.02, -50.0, 50.0),), "small |u|",
                 claimable=_share_of("bias_v", st.min_null_bias * p["valve_max_command_v"])),
            cand("valve_dynamics", None, (lin("valve_tau_s", 1e-3, 0.0, 100.0, step=2.0),), "du/dt",
                 claimable=_share_of("tau_s", st.min_valve_lag * self.slowest_spool_lag())),
            cand("valve_deadband", None, (lin("valve_deadband_half_width_v", 0.05, 0.0, 40.0),), "small |u|",
                 claimable=wider_than_null),
            # A play is a band of the command like a dead band: narrower than the valve's null
            # tolerance it is the valve's null form (a friction asymmetry's small reversal error
            # reads as such a play), not a play of its own.
            cand("valve_hysteresis", None, (lin("valve_hysteresis_half_width_v", 0.05, 0.0, 40.0),), "sign(du/dt)",
                 claimable=wider_than_null),
            cand("supply_pressure_sag", None, (lin("supply_resistance_pa_s_per_m3", 1e9, 0.0, 1e3),), "v",
                 claimable=_share_of("resistance_pa_s_per_m3", st.min_sag * p["supply_pressure_pa"]
                                     / max(p["valve_rated_flow_m3_s"], 1e-12))),
            cand("internal_leakage", None, (lin("leakage_coeff_m3_per_s_pa", 1e-12, 0.0, 1e3),), "load pressure",
                 claimable=_share_of("coeff_m3_per_s_pa", st.min_leakage * p["valve_rated_flow_m3_s"]
                                     / max(p["supply_pressure_pa"], 1.0)),
                 shows=self.leak_flow_share if leak_shows else None, shows_against_rest=leak_shows,
                 still=self.standstill if st.still_share > 0 else None),
            cand("friction_asymmetry", None, (lin("friction_coulomb_diff_n", 50.0, -100.0, 100.0),), "sign(v)",
                 claimable=_asymmetric(st.min_asymmetry),
                 alternate=cand("friction_asymmetry", None, (lin("friction_coulomb_diff_weighed_n", 50.0, -100.0, 100.0),),
                                "sign(v)", claimable=_asymmetric(st.min_asymmetry), holds=_weight_held)
                 if st.asymmetry_weighed and p["gravity_m_s2"] > 0 else None),
            cand("pressure_dependent_friction", None, (lin("friction_pressure_coeff_n_per_pa", 1e-6, 0.0, 1e3, step=2.0),),
                 "(p_a + p_b) sign(v)"),
            cand("entrained_air", None, (lin("air_fraction", 1e-3, 0.0, 100.0, step=5.0),), "p_a + p_b",
                 shows=self.low_pressure if st.signature_contrast > 0 else None),
        ]
        if p["valve_linear_flow"] > 0.5:  # a declared linear valve may in truth feel the load pressure
            out.append(cand("load_pressure_feedback", None, (), "load pressure", switch=(("valve_linear_flow", 0.0),)))
        if p["specimen_stiffness_n_m"] > 0 and "f" in channels:
            out += self.closure_candidates(rec.columns["y"], p["specimen_zero_force_position_m"], p["specimen_stiffness_n_m"],
                                           rec.columns["f"])
        return [c for c in out if all(has_key(p, f.key) for f in c.frees)]

    def probes(self, residual: dict[str, np.ndarray], rate_hz: float) -> list[Candidate]:
        """Structure outside EFFECTS.md that a rig shows (project ids, never reported as findings):
        a force, a friction or a damping over part of the stroke (a load over a band, a scored
        bore, an end cushion), placed along the travel the record visits; and a ripple of the
        supply at a frequency that stands out of the pressure residual's spectrum but not out of
        the command's (a pump's pistons)."""
        p, rec = self.nominal, self.rec
        y = np.asarray(rec.columns["y"], dtype=float)
        lo, hi = float(np.nanpercentile(y, 1)), float(np.nanpercentile(y, 99))
        span = max(hi - lo, 1e-4)
        area = 0.5 * (p["area_a_m2"] + p["area_b_m2"])
        force_unit = max(1.0, 0.01 * area * p["supply_pressure_pa"])  # 1 % of the actuator's force
        v = np.gradient(y, 1.0 / rate_hz)
        damping_unit = force_unit / max(float(np.nanstd(v)), 1e-4)
        out: list[Candidate] = []
        # "Part of the stroke": at most a third of the travel the record visits. A force that
        # varies smoothly over all of it is the model's form (a line, a hose, a spring), not an
        # effect outside the vocabulary.
        widest = max(span / 3 / p["friction_bump_width_m"], 0.2)
        for width in (span / 12, span / 4):
            for centre in np.linspace(lo, hi, 7):
                band = (lin("friction_bump_position_m", span / 20, 0.0, 1e3, step=0.2, origin=0.0),
                        logf("friction_bump_width_m", 0.1, widest, step=0.1))
                # the band's centre and width start where placed (the width as a factor of 5 mm)
                starts = (band[0].coord(float(centre), 0.0), float(np.log(width / p["friction_bump_width_m"])))
                for effect, key, unit, low in (("position_force", "force_bump_n", force_unit, -1e3),
                                              ("position_friction", "friction_bump_n", force_unit, 0.0),
                                              ("position_damping", "damping_bump_n_s_m", damping_unit, 0.0)):
                    out.append(Candidate(effect, None, (lin(key, unit, low, 1e3), *band), "y", starts=starts,
                                         fields=(("amplitude", key), ("centre_m", "friction_bump_position_m"),
                                                 ("width_m", "friction_bump_width_m"))))
        for f in _ripple_frequencies(rec, residual, rate_hz):
            unit = max(1e3, 0.001 * p["supply_pressure_pa"])
            for first, second in (("supply_ripple_sin_pa", "supply_ripple_cos_pa"), ("supply_ripple_cos_pa", "supply_ripple_sin_pa")):
                out.append(Candidate("supply_ripple", None, (lin(first, unit, -1e3, 1e3), lin(second, unit, -1e3, 1e3)),
                                     "constant", starts=(0.0,), switch=(("supply_ripple_hz", f),), tone_hz=f,
                                     fields=(("sin_pa", "supply_ripple_sin_pa"), ("cos_pa", "supply_ripple_cos_pa"),
                                             ("frequency_hz", "supply_ripple_hz"))))
        return [c for c in out if all(has_key(p, f.key) for f in c.frees)]


def _spool_lo() -> float:
    """The lower bound of the base's spool frequency, as a share of its nominal (`OTHER_FREES`)."""
    [f] = [f for f in OTHER_FREES if f.key == "valve_natural_hz"]
    return float(np.exp(f.lo)) if f.log else float(f.lo)


def spool_lag(p: Any) -> float:
    """The lag [s] of the base model's own second-order spool at low frequency, 2*zeta/omega_n
    (0 for a static valve): a first-order lag shorter than it is the spool's form."""
    hz = float(p["valve_natural_hz"])
    return 2.0 * float(p["valve_damping"]) / (2.0 * np.pi * hz) if hz > 0 else 0.0


def spool_slowed_by(p: Any, delay: dict[str, float]) -> dict[str, float] | None:
    """The base's own form that lags as a reading's delay does (`Candidate.form`): its spool with
    the low-frequency lag 2*zeta/omega_n lengthened by the delay, the damping kept (within the
    spool's bounds, which `Model.moved_to` keeps)."""
    lag = spool_lag(p) + float(delay.get("delay_s", 0.0))
    if not (lag > 0.0 and np.isfinite(lag)):
        return None
    return {"valve_natural_hz": 2.0 * float(p["valve_damping"]) / (2.0 * np.pi * lag)}


def _calibrated_off(least: float) -> Callable[[dict[str, float]], bool]:
    """A gain off by `least` (min_gain_error) at least: within it a transducer is inside its
    calibration tolerance, and a fit's gain there is taking up the model's form, not a fault."""
    return lambda p: abs(p["gain"] - 1.0) >= least


def _not_a_tolerated_gain(rec: Record, channel: str, min_gain_error: float) -> Callable[[dict[str, float]], bool]:
    """An offset claimed only where no gain inside calibration tolerance could read the same: a
    gain error e reads e·median + e·(reading − median); an offset o is that with e = o/median
    whenever the varying part, |o|·spread/median, is lost in the noise (a supply gauge reads
    nearly constant), and such an e under MIN_GAIN_ERROR is a calibrated transducer."""
    y = np.asarray(rec.columns[channel], dtype=float)
    y = y[np.isfinite(y)]
    median = float(np.median(np.abs(y))) if y.size else 0.0
    spread = float(np.std(y)) if y.size else 0.0
    noise = ft.reading_noise(rec.meta, channel, y)

    def claimable(p: dict[str, float]) -> bool:
        o = abs(next(iter(p.values())))
        return median <= 0 or o >= min_gain_error * median or o * spread / median > noise

    return claimable


def _share_of(name: str, least: float) -> Callable[[dict[str, float]], bool]:
    """An effect claimed only where its parameter `name` reaches `least` in size (0: always)."""
    return lambda p: abs(p[name]) >= least


def _asymmetric(least: float) -> Callable[[dict[str, float]], bool]:
    """Coulomb friction that differs with direction by `least` (min_asymmetry) of its mean at
    least (a smaller difference is within what the friction law's form, Stribeck or
    pre-sliding, mimics)."""
    def claimable(p: dict[str, float]) -> bool:
        pos, neg = p["coulomb_pos_n"], p["coulomb_neg_n"]
        return abs(pos - neg) >= least * 0.5 * (abs(pos) + abs(neg))

    return claimable


def _ripple_frequencies(rec: Record, residual: dict[str, np.ndarray], rate_hz: float, top: int = 2) -> list[float]:
    """Frequencies [Hz] at which the pressure residuals' spectrum peaks far above its
    neighbourhood while the command's does not (a disturbance the experiment did not make)."""
    chans = [c for c in ("p_s", "p_a", "p_b") if c in residual]
    if not chans:
        return []
    n = len(rec.columns["t"])
    nper = int(min(n, max(256, 2 ** int(np.log2(rate_hz * 4)))))
    power = 0.0
    for c in chans:
        r = np.nan_to_num(np.asarray(residual[c], dtype=float))
        f, pxx = welch(r - r.mean(), rate_hz, nper)
        power = power + pxx / max(float(np.median(pxx)), 1e-300)
    cmd = np.nan_to_num(np.asarray(rec.columns.get("u", rec.columns["y"]), dtype=float))
    _, pcmd = welch(cmd - cmd.mean(), rate_hz, nper)
    pcmd = pcmd / max(float(np.median(pcmd)), 1e-300)
    out: list[float] = []
    order = np.argsort(power)[::-1]
    for i in order:
        if f[i] < 2.0 or f[i] > 0.45 * rate_hz:
            continue
        near = power[max(0, i - 8): i + 9]
        if power[i] < 20.0 * float(np.median(near)) or pcmd[i] > 0.1 * float(np.max(pcmd)):
            continue
        if all(abs(f[i] - g) > 3 * (f[1] - f[0]) for g in out):
            out.append(_sharpened(residual, chans, rate_hz, float(f[i]), float(f[1] - f[0])))
        if len(out) >= top:
            break
    return out


def _sharpened(residual: dict[str, np.ndarray], chans: list[str], rate_hz: float, f0: float, bin_hz: float) -> float:
    """The frequency near `f0` (a spectral estimate's bin) at which the residuals' periodogram
    peaks, to a fortieth of 1/duration: a ripple fitted at a frequency off by more drifts out of
    phase over the record and averages out. Each residual is shifted down by `f0` and averaged
    over blocks much shorter than 1/bin, so the fine search runs on a few samples per second."""
    n = len(next(iter(residual.values())))
    t = np.arange(n) / rate_hz
    shift = np.exp(-2j * np.pi * f0 * t)
    block = max(1, int(rate_hz / (20.0 * bin_hz)))
    m = n // block
    tb = t[: m * block].reshape(m, block).mean(axis=1)
    zs = []
    for c in chans:
        r = np.nan_to_num(np.asarray(residual[c], dtype=float))
        r = (r - r.mean()) / max(float(np.std(r)), 1e-300)
        zs.append((r * shift)[: m * block].reshape(m, block).mean(axis=1))
    z = np.array(zs)

    def power(offsets: np.ndarray) -> np.ndarray:
        return (np.abs(z @ np.exp(-2j * np.pi * np.outer(tb, offsets))) ** 2).sum(axis=0)

    span = n / rate_hz
    best = 0.0
    for half, step in ((1.5 * bin_hz, 0.25 / span), (0.25 / span, 0.025 / span)):
        grid = np.arange(best - half, best + half + step / 2, step)
        best = float(grid[int(np.argmax(power(grid)))])
    return f0 + best
