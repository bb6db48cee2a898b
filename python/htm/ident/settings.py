"""Every knob of the diagnosis path in one place: `SearchSettings`.

Each field carries its unit and the reason for its value (`dataclasses.fields(...)[i].metadata`,
`SearchSettings.describe()`); `diagnose(rec, settings=...)` passes one down to the fit, the
search, the verdict on structure left and the model family's claim thresholds, and writes it into
report.json (`settings`). The defaults are the values the search was built and checked with (the
effect matrices and the external set); a changed setting is a changed diagnosis, and the report's
decision trace (`trace`) names the rule each decision applied.

What is not here: the bounds and steps of the models' own free parameters (`valve.RIG_FREES`,
`loop.LoopFamily._base_frees`: they describe the physics of a rig, not the search) and the
signal-processing constants of `features` and `sim` (a noise floor's estimator, the simulator's
tolerance), which serve other commands too.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any


def knob(default: Any, unit: str, reason: str) -> Any:
    """A setting with its unit and the reason for its value."""
    if isinstance(default, (tuple, list)):
        return field(default=tuple(default), metadata={"unit": unit, "reason": reason})
    return field(default=default, metadata={"unit": unit, "reason": reason})


@dataclass(frozen=True)
class SearchSettings:
    """The knobs of `diagnose` (see the module docstring). Frozen: change one with
    `dataclasses.replace(DEFAULT, min_gain=0.1)` or `SearchSettings(min_gain=0.1)`."""

    # --- the record and its split (diagnose, fit) -------------------------------------------
    min_samples: int = knob(200, "samples", "a record shorter than this carries too little to fit a model of ~20 parameters")
    work_s: float = knob(20.0, "s", "fits use the record's first seconds (interleaved fit/validation blocks); the rest is held out")
    block_s: float = knob(0.3, "s", "interleaved fit/validation blocks: short enough that every phase of the experiment "
                                    "(holds, ramps, sines, steps) falls on both sides")
    excitation_noise: float = knob(50.0, "x position noise", "a record whose position moves less than this many noise "
                                                             "floors carries no information: refused")
    excitation_stroke: float = knob(1e-4, "x stroke", "...nor less than this share of the stroke")
    screen_scale_noise: float = knob(10.0, "x noise", "a sensor effect's parameter unit is this many noise floors of its "
                                                      "channel (or 1e-6 of its largest reading)")
    cannot_follow: float = knob(0.5, "share of the channel's std", "a fitted model whose held-out error exceeds this share "
                                                                   "of a channel's own variation does not follow it at all")
    max_findings: int = knob(3, "findings", "effects added at most (greedy forward selection)")
    max_refits: int = knob(2, "candidates per round", "screened candidates refitted per round")
    # --- the least-squares fit (fit.fit) ----------------------------------------------------
    base_iters: int = knob(10, "Jacobians", "budget of the base model's fit")
    refit_iters: int = knob(6, "Jacobians", "budget of a refit with a candidate (and of the same fit without one)")
    polish_iters: int = knob(15, "Jacobians", "budget of polishing a contender before it is chosen")
    common_iters: int = knob(3, "Jacobians", "a contender's own parameters fitted on the other contender's base (base held)")
    tone_iters: int = knob(1, "Jacobians", "a tone's amplitudes with the model held (nearly linear)")
    ftol: float = knob(2e-3, "relative cost", "a fit stops after two iterations that gain less than this share of the cost")
    noise_cost: float = knob(1.2, "noise-scaled mean square", "a fit at or below this on every channel is at its noise: stops")
    radius_max: float = knob(1.0, "normalised coordinate", "largest LM step (a factor e for a log parameter): far jumps land "
                                                           "in wrong basins (friction trading against compressibility)")
    jacobian_every: int = knob(2, "iterations", "the Jacobian is differenced afresh every this many iterations (Broyden between)")
    predicted_stop: float = knob(0.0, "x ftol", "a fit may also stop after one iteration that gains less than ftol when "
                                                "the Gauss-Newton model of its next step promises less than this many "
                                                "ftol (a Jacobian and three trials saved). Off (0: two small iterations): "
                                                "at 1 the refit without a new effect stops early, and a candidate takes "
                                                "credit for the base's convergence (a foreign-rig record, seed 2 fr04, "
                                                "gains a false leak; 20-45 % fewer simulations on benchmarks/diagnose.py)")
    warm_jacobian: bool = knob(False, "switch", "a fit that starts where an earlier fit ended (the round's refit without a "
                                                "new effect, a contender's polish) takes the Jacobian that fit left there "
                                                "for its first differencing (one simulation per parameter saved; 7-10 % "
                                                "fewer simulations on benchmarks/diagnose.py, same findings there). Off: "
                                                "with it on, a foreign-rig record (seed 2 fr08, a supply ripple) gains a "
                                                "false dead band — the fits' paths move, and a decision with them")
    prior_share: float = knob(0.003, "share of the noise-level cost", "weak prior on parameters that have one: curvature for "
                                                                      "flat valleys without moving what the data determine")
    # --- the search: screen, refit, judge, break ties, backward check -------------------------
    systematic: float = knob(1.0, "systematic ratio (residual / noise)", "the search stops when no channel's non-noise "
                                                                         "residual stands above its noise floor")
    screen_chi2: float = knob(25.0, "chi^2", "evidence a candidate's signature must carry before it is refitted")
    screen_fraction: float = knob(0.01, "share of the fit cost", "...and as a share of the fit cost")
    refit_share: float = knob(0.3, "share of the best screened gain", "candidates refitted per round: those within this "
                                                                      "share of the best screened gain")
    widen_when_pinned: bool = knob(True, "on/off", "when no refitted candidate pays off while a parameter the metadata "
                                                   "states sits at its bound (the base in a wrong basin, the screen's "
                                                   "ranking read there), the rest of the screened candidates are refitted "
                                                   "once before the search ends (a record is refused only after that)")
    scan_octaves: tuple[int, ...] = knob((-1, 0, 1, 2, 3, 4, 5, 6), "powers of 2 of the parameter's step",
                                         "sizes of a candidate's first parameter tried before its refit (a delay's, a dead "
                                         "band's cost is not convex)")
    min_gain: float = knob(0.05, "relative held-out cost", "a refit must cut the held-out cost by this share (and win by BIC) "
                                                           "to count; also the margin under which two contenders are tied")
    min_share: float = knob(0.2, "share of a channel's systematic residual", "and remove this share of some channel's "
                                                                            "residual above its noise: shaving a few percent "
                                                                            "off a large misfit is bending to the model's form")
    significant: float = knob(3.0, "standard deviations of white noise's mean square", "a channel has a systematic part to "
                                                                                       "share only this far above its noise")
    contender_dbic: float = knob(0.5, "share of the best dBIC", "a second candidate that pays off is polished beside the "
                                                                "best when its dBIC reaches this share of the best's")
    preference: tuple[str, ...] = knob(
        ("sensor_offset", "valve_null_bias", "sensor_gain", "sensor_delay", "valve_dynamics", "internal_leakage",
         "friction_asymmetry", "valve_deadband", "valve_hysteresis", "supply_pressure_sag",
         "pressure_dependent_friction", "entrained_air", "load_pressure_feedback", "specimen_nonlinearity"),
        "effect ids, most common first", "which of two effects the record cannot tell apart is named")
    sibling_ratio: float = knob(2.0, "ratio of sizes", "a sensor fault found on one reading whose sibling (the other "
                                                       "chamber's, measured alike) pays off with the same fault, same sign "
                                                       "and within this factor in size, is common to both: the plant's form "
                                                       "(lines, the valve), not two faults (0: no sibling check)")
    sibling_other_kind: bool = knob(True, "switch", "a level fault (offset, gain) chosen on a reading with a sibling "
                                                    "is weighed also against the sibling's other level fault, refitted "
                                                    "and compared on a common base: the base's pressure levels (supply, "
                                                    "tank) move both chambers together, so one chamber's offset can be "
                                                    "fitted as the other chamber's gain (foreign rig quick seed 4 fr25: "
                                                    "an offset on p_b found as a gain on p_a). Where the fault moves, "
                                                    "that reading's own offset and gain are weighed as one sensor's "
                                                    "(seed 2 fr16: offset p_b -> gain p_a -> offset p_a, the truth). "
                                                    "Weighed only where the same fault refitted on the sibling came within "
                                                    "sibling_ratio of the chosen one's size, of either sign (0.56-1.01 on "
                                                    "the records where it moved the fault or was close; 0.03 on benchmarks/diagnose.py's "
                                                    "p_a offset, whose 97 simulations it saves)")
    resettle: bool = knob(True, "switch", "a round whose model is the very point where the last round's refit without a "
                                          "new effect ended converged (two gains below ftol: a candidate left the pool "
                                          "as too small, nothing else changed) does not refit it again (it would gain "
                                          "less than ftol an iteration; a Jacobian and its trials saved) and screens "
                                          "the same point again (from the cache); benchmarks/diagnose.py's outside-the-table "
                                          "path 844 -> 528 simulations, the same verdict")
    backward_stop: float = knob(0.5, "relative fit-block cost (as dcost reads it)",
                                "the backward check's refit without a finding stops once, even gaining on each iteration "
                                "left twice the best share any iteration so far gained (no less than backward_rate, at most "
                                "half), its fit-block cost "
                                "would stay this far above the model with the finding (ten times min_gain): the finding "
                                "is kept whatever the rest of that refit does. A finding that goes after all is decided "
                                "on refits run to their end (0: off). The two-effects path of benchmarks/diagnose.py: "
                                "backward check 252 -> 150 simulations, both findings kept as before")
    backward_rate: float = knob(0.25, "share of the fit cost per iteration", "the least gain per iteration backward_stop "
                                                                           "assumes (the fits seen gain 1-30 % an "
                                                                           "iteration, fastest on a start far off)")
    close_margin: float = knob(0.2, "share of a threshold", "a decision whose deciding number lies within this share of "
                                                            "its threshold is marked close in the trace")
    # --- structure outside the vocabulary (probes) -----------------------------------------
    probe_gain: float = knob(0.1, "relative held-out cost", "a probe for structure outside the vocabulary must cut the "
                                                            "held-out cost by this much")
    probe_share: float = knob(0.5, "share of a channel's systematic residual (or of a band's power)",
                              "...and account for this share: structure outside the vocabulary dominates what is left")
    probe_refits: int = knob(2, "probes", "screened probes refitted")
    probe_one_first: bool = knob(True, "switch", "the screened probes are refitted one at a time, best screened first, "
                                                 "and the first that pays off is the evidence of structure outside the "
                                                 "vocabulary (the verdict needs one): the next one's refit (~100 "
                                                 "simulations of a 60 s record) is saved. Off: the top probe_refits are "
                                                 "refitted side by side and the best by dBIC is reported (the outside-the-table "
                                                 "path: probes 218 -> 127 simulations, the same verdict)")
    # --- the verdict on structure left (floor) ---------------------------------------------
    unexplained: float = knob(1.5, "systematic ratio", "structure is reported unexplained above this (a clear margin over "
                                                       "`systematic`)...")
    margin: float = knob(2.0, "x the model's own floor", "...and above this many times the model's own floor")
    gross: float = knob(10.0, "x the unexplained threshold", "structure this far beyond is no form error of a model that "
                                                             "fits: unexplained whatever a probe says; refused with a rig "
                                                             "parameter pinned")
    floor_realisations: int = knob(2, "synthetic records", "records of the fitted model itself (its prediction with the "
                                                           "record's noise) its own floor is the worst of")
    form_lags_s: tuple[float, ...] = knob((0.004, 0.02, 0.1), "s", "first-order lags of the model's own signals in the "
                                                                    "linear map of its form errors")
    form_ridge: float = knob(1e-2, "per sample", "ridge weight of the form map's standardised regressors: the lags are "
                                                 "nearly collinear and must not extrapolate to the held-out samples")
    # --- claim thresholds of the valve family's effects ---------------------------------------
    min_asymmetry: float = knob(0.1, "share of the mean Coulomb friction", "a few percent is the friction law's form")
    min_gain_error: float = knob(0.01, "relative gain error", "transducers are calibrated to 0.1-0.5 %")
    min_null_bias: float = knob(0.002, "share of the rated command", "a servo-valve's null is set to about 0.1 % of it; "
                                                                     "a dead band or a play of the command (valve_hysteresis) "
                                                                     "narrower than that is the valve's null form, not a band")
    min_leakage: float = knob(0.01, "share of the rated flow at supply", "a servo-valve's own null leakage is 1-3 % of "
                                                                         "it: a piston leak below that is the valve's null "
                                                                         "flow in another form (the base's underlap takes it)")
    min_sag: float = knob(0.04, "share of the supply pressure, at the valve's rated flow",
                          "a power unit's filters, hoses and accumulator drop a few percent at full flow, and the lines' "
                          "and the valve's pressure-flow form mimic that much: a sag below this is not a sagging supply")
    max_others_worse: float = knob(0.5, "noise variances of the other readings' held-out mean square",
                                   "a sensor delay is a fault of one reading: the others see it only through the loop, "
                                   "and there a true delay leaves them as they were or fits them better (a refit moves them "
                                   "by a sliver of their noise). A delay that buys its own reading at the cost of the others "
                                   "(a ripple, a lag of the valve) is the loop's phase moved into one reading: not claimed "
                                   "where the others' mean square rises by more than this")
    delay_own_level: float = knob(0.25, "x the worst other reading's held-out mean square before it (both over their noise)",
                                  "a sensor delay that leaves the others worse by more than max_others_worse is still its "
                                  "reading's fault where that reading was the model's worst, and it takes most of its "
                                  "systematic error away and leaves it this far below the worst other reading (half its RMS "
                                  "or less): a time shift that was "
                                  "the reading's whole misfit, the others' rise the base's own form that parameters bent "
                                  "around the delay had hidden. A delay standing in for another phase leaves its reading "
                                  "about as far off as the others or further (measured: 2.2-220 x on the foreign and "
                                  "external records it was refused on, 0.034 and 0.065 x for the two true delays; a y "
                                  "delay standing in for a valve's lag passed at 0.028 and 0.213 on two foreign records, "
                                  "where the lag won the tie-break)")
    delay_own_share: float = knob(0.5, "share of the delayed reading's systematic residual",
                                  "...and the share of that reading's systematic error (its held-out mean square above "
                                  "the noise) the delay must take away for `delay_own_level` to apply: most of it, the "
                                  "reading's whole misfit a time shift (the two true delays took 0.999 and 0.98)")
    signature_contrast: float = knob(2.0, "x the effect's size at the record's typical state",
                                     "an effect whose size varies over the record (entrained air: its compliance, "
                                     "~1/p^2) must cut the held-out error on the samples where it is at least this "
                                     "many times its size at the typical state (a chamber's pressure at or below "
                                     "1/sqrt of this times its median, absolute): at the typical state it is a level "
                                     "the bulk modulus and the dead volumes set as well. Gaining only there, or none "
                                     "such samples held out, it is not claimed (a friction asymmetry's record, the "
                                     "external set with seeds + 1000 rec_e2: air 0.094 gained on the fast ramps at "
                                     "~90 bar and lost on the steps that reach 45 bar). 0: off")
    shows_ratio: float = knob(2.0, "ratio of the error shares left", "an effect judged also against the rest of the "
                              "record where it shows (an internal leak: where the load pressure drives a leak flow that "
                              "is at least signature_contrast times its typical share of the actuator's flow, slow motion "
                              "under load) must leave there at most this many times the share of the held-out error it "
                              "leaves elsewhere: a true leak cuts the error there as much or more (htm's own leak records, judged: 0.25-0.5), a leak "
                              "standing in for a foreign rig's line dynamics gains mostly where the motion is fast "
                              "(foreign seed 2 fr16: 2.8 polished). 0: a leak is not judged where it shows")
    shows_gain: float = knob(0.75, "ratio of the error shares taken", "a leak that fails shows_ratio still passes where the "
                             "share of the held-out error it takes where it shows is at least this many times the share it "
                             "takes elsewhere: a leak that explains nearly all of the error everywhere leaves shares near the "
                             "floor on both sides, and their ratio is the floor's scatter, not a signature (a foreign rig's "
                             "force-controlled leak, f_leak seed 2 fr17: 0.044 left where it shows against 0.018 elsewhere, "
                             "i.e. 96 % taken against 98 %; the stand-in of fr16 takes 42 % against 80 %). 0: off (the ratio alone judges)")
    still_share: float = knob(0.6, "share of the held-out error at standstill", "an internal leak must take at least this "
                              "share of the held-out error where the actuator stands still (|v| within twice its reading's "
                              "noise floor): there its flow has no motion, compressibility or line dynamics beside it in "
                              "the flow balance, so a leak the record holds takes most of the error there (foreign leak "
                              "records, the 22 verdicts of true leaks that paid off: 0.67-0.98 taken), while a leak "
                              "standing in for a foreign rig's line damping or a valve lag gains in motion and little at "
                              "rest (foreign quick seed 4 fr28: 0.14-0.16 taken at rest against 0.51-0.69 of the whole; "
                              "fr18 0.21; a leak beside a supply sag, delay set seed 1 fr14: 0.42 and, refitted larger, "
                              "0.52). Set between the two (these records: other seeds judge it). Restricted to the samples "
                              "under load it separates worse (a force-controlled true leak, f_leak seed 1: 0.67 taken at "
                              "rest, -0.44 at rest under load). 0: off")
    still_min_samples: float = knob(0.02, "share of the held-out samples", "the standstill test of still_share is made "
                                    "only where at least this share of the held-out samples stands still: a record that "
                                    "barely stops cannot tell a leak from a stand-in there (judged as before)")
    asymmetry_weighed: bool = knob(True, "switch", "a friction asymmetry d on a vertical rig is refitted also with the weight "
                                                   "it trades with held (the mass lowered by d/g as d grows), the better fit "
                                                   "kept: in motion d acts "
                                                   "as a weight whichever the direction, and the base fit without it has "
                                                   "taken d into the mass (inertia, and with it the oil's stiffness bent to "
                                                   "keep the resonance); fitted plainly the search stays in that basin and "
                                                   "an effect that reshapes the stiffness (entrained air) stands in for the "
                                                   "rest (the external set with seeds + 1000 rec_e2: mass 74 kg against "
                                                   "53 kg; fitted that way alone, a matrix pair of seed set B kept too little of "
                                                   "its 1100/500 N and read unexplained). Off: the plain asymmetry only")
    min_valve_lag: float = knob(1.0, "x the spool's own lag 2*zeta/omega_n", "a first-order valve lag shorter than the lag "
                                                                             "of the base model's own second-order spool "
                                                                             "(declared; undeclared, the slowest its bound "
                                                                             "admits, 60 Hz at damping 0.7) is the spool's "
                                                                             "form, not a lag of its own")
    delay_against_form: bool = knob(True, "switch", "a reading's delay that pays off is weighed also against the model "
                                                    "without it refitted from the base's own form that lags so (the "
                                                    "family's `Candidate.form`: the spool slowed by the delay): the record "
                                                    "must prefer the delay (dBIC, min_gain) and its own reading be no "
                                                    "worse with it than that form leaves it (by min_share). The base fit "
                                                    "can leave its spool too fast, and a delay on one reading then takes "
                                                    "the spool's lag (foreign quick seed 4 fr14: a 2.2 ms y delay, the "
                                                    "base spool at 335 Hz, the true one at 101 Hz: y 0.55 worse than "
                                                    "with the spool at 147 Hz); a true delay stands against a spool "
                                                    "that lags every reading (the 5 true delays found before, kept: the "
                                                    "foreign delay set's 3, the external rec_f5 on both seed sets)")
    min_sensor_delay: float = knob(0.0, "sample periods", "a reading's transport delay shorter than this is not claimed "
                                                          "(where in its sample period a reading is taken, a sub-sample "
                                                          "phase the base model's form leaves). Off: at 0.25 the clean "
                                                          "foreign seed 6 fr10 lost its false 0.18 ms delay on v, but the "
                                                          "external set with seeds + 1000 rec_e2 (a vertical rig's "
                                                          "asymmetry) gained entrained air 0.016 after its asymmetry — "
                                                          "the 0.37 ms p_b delay it had claimed first, and dropped at the "
                                                          "end, had held the p_b phase that the air then took (STRICT "
                                                          "12 -> 11 of 13)")

    def describe(self) -> dict[str, dict[str, Any]]:
        """{name: {value, unit, reason}} of every setting."""
        return {f.name: {"value": _plain(getattr(self, f.name)), "unit": f.metadata["unit"], "reason": f.metadata["reason"]}
                for f in dataclasses.fields(self)}

    def to_json(self) -> dict[str, Any]:
        """{name: value} (report.json's `settings`)."""
        return {f.name: _plain(getattr(self, f.name)) for f in dataclasses.fields(self)}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "SearchSettings":
        known = {f.name: f for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - set(known))
        if unknown:
            raise ValueError(f"unknown search setting(s): {', '.join(unknown)}")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})


def _plain(v: Any) -> Any:
    return list(v) if isinstance(v, tuple) else v


DEFAULT = SearchSettings()
