"""Which of the foreign rig's features makes a diagnosis go wrong: rebuild one case of a seed with
one feature neutralised at a time, everything else drawn alike, and write each as a record.

    python neutralise.py --seed S --case CASE_ID --out DIR [asis] [lugre] [lines]

`lugre`: the bristles 100 x stiffer and 100 x less damped (friction without pre-sliding);
`lines`: the lines' laminar and turbulent resistances x 0.001 (their volume stays). Records are
DIR/records/<variant>.csv.gz with their truth beside, as `cases.py` writes them; diagnose each
(`htm diagnose DIR/records/<variant>.csv.gz --out ...`) and compare the findings.
"""
from __future__ import annotations

import argparse

import cases as C

VARIANTS = ("asis", "lugre", "lines")


def neutralise(rig: dict, variant: str) -> None:
    if variant == "lugre":
        rig["bristle_stiffness_n_m"] *= 100.0
        rig["bristle_damping_n_s_m"] *= 0.01
    elif variant == "lines":
        for k in ("line_r_lam_a", "line_r_lam_b", "line_r_turb_a", "line_r_turb_b"):
            rig[k] *= 1e-3


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--case", required=True, choices=sorted(C.CASE_BY_ID))
    ap.add_argument("--out", required=True)
    ap.add_argument("variants", nargs="*", default=list(VARIANTS), choices=VARIANTS)
    a = ap.parse_args()
    for v in a.variants:
        b = C.build_case(C.CASE_BY_ID[a.case], a.seed)
        neutralise(b["rig"], v)
        b["rig_sim"] = b["rig"]
        sim = C.simulate_case(b)
        C.write_case(b, sim, v, a.out)
        print(v, "sane" if sim["sane"] else "the closed loop misbehaves", flush=True)


if __name__ == "__main__":
    main()
