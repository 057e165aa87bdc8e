"""The plain weave's compaction curve beside the one published measure we could read
(docs/compaction.md: "Against measurements").

Published: Saunders, Lekakou & Bader, "Compression and microstructure of fibre plain woven cloths
in the processing of polymer composites", Composites Part A 29 (1998) 443-454. Its abstract: the
compression of dry plain woven cloths, in stacks of 5, 10 and 20, "followed a power law
relationship between pressure and Vf where the power law index was determined to be approximately
equal to 10": p ~ Vf^10, so Vf grows by 10^(1/10) = 1.26 from 0.1 to 1 MPa. Only the abstract can
be read here (no network): no absolute thickness or Vf at 0.1 and 1 MPa to set beside ours.

Ours: TexGen's plain weave (reference/models/plain.tg3: 2 mm spacing, yarns 1.8 x 0.3 mm, no fibre
data, so an intra-yarn fraction of 0.65 or --yarn-vf's), K = 50 MPa (not fitted), 1 ply and N plies
nested at random offsets (plies.random_offsets, seed 0), pressed in --steps equal steps to a Vf
of --target times the yarns' (0.92: beyond 1 MPa on every curve here, short of the packing limit).
Each curve's Vf and thickness per ply at 0.1 and 1 MPa are interpolated on log p, and its index
n = ln 10 / ln(Vf(1 MPa) / Vf(0.1 MPa)).

    python3 bench/compaction_published.py [--plies 1 2] [--yarn-vf 0.65 0.5] [--seed 0.5]
                                          [--steps 10] [--target 0.92] [--out output/compaction_published.json]
"""

import argparse
import itertools
import json
import math
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
MODEL = REPO / "reference" / "models" / "plain.tg3"
PUBLISHED_INDEX = 10.0  # Saunders, Lekakou & Bader 1998 (abstract): p ~ Vf^10, 5-20 dry plain woven cloths


def at_pressure(curve, plies: int, p: float) -> tuple[float, float] | None:
    """(Vf, thickness per ply [mm]) at pressure p [MPa], interpolated on log p; None off the curve."""
    pressure = np.asarray(curve.pressure[1:])  # (the relaxed point has no pressure)
    if len(pressure) < 2 or not pressure.min() <= p <= pressure.max():
        return None
    lp = np.log(pressure)
    vf = math.exp(np.interp(math.log(p), lp, np.log(curve.vf[1:])))
    return vf, math.exp(np.interp(math.log(p), lp, np.log(curve.thickness[1:]))) / plies


def main() -> None:
    from mpi4py import MPI

    import textile_fenicsx as tfx
    from textile_fenicsx.model.metrics import with_yarn_vf
    from textile_fenicsx.model.plies import random_offsets, stack
    from textile_fenicsx.pipeline.compaction import CompactionTarget

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--plies", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--yarn-vf", type=float, nargs="+", default=[0.65, 0.5])
    parser.add_argument("--seed", type=float, default=0.5)
    parser.add_argument("--steps", type=int, default=10)
    parser.add_argument("--target", type=float, default=0.92, help="the target Vf over the yarns' Vf (0.92)")
    parser.add_argument("--out", type=Path, default=REPO / "output" / "compaction_published.json")
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    plain = tfx.read(MODEL)
    records = []
    for plies, phi0 in itertools.product(args.plies, args.yarn_vf):
        if comm.rank == 0:
            print(f"compaction beside the published index: {plies} ply(ies), yarn Vf {phi0}", file=sys.stderr,
                  flush=True)
        model = with_yarn_vf(plain, phi0)
        if plies > 1:
            model = stack(model, plies, random_offsets(model, plies, 0))
        r = tfx.solve(model, seed=args.seed, comm=comm,
                      compaction=CompactionTarget(50.0, vf=args.target * phi0, steps=args.steps))
        curve = r.compaction
        low, high = at_pressure(curve, plies, 0.1), at_pressure(curve, plies, 1.0)
        index = math.log(10) / math.log(high[0] / low[0]) if low and high else None
        records.append({"plies": plies, "yarn_vf": phi0, "relaxed_vf": curve.vf[0],
                        "relaxed_thickness_per_ply_mm": curve.thickness[0] / plies, "at_0.1_MPa": low,
                        "at_1_MPa": high, "index": index, "stopped": curve.reason, "passed": r.verdict["passed"],
                        "failures": [f["message"] for f in r.verdict["failures"]],
                        "curve": curve.as_dict()})
    if comm.rank != 0:
        return
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(records, indent=1))
    print("| plies | yarn Vf | relaxed Vf | Vf at 0.1 MPa | Vf at 1 MPa | thickness per ply at 0.1 / 1 MPa mm | "
          f"index n (published: about {PUBLISHED_INDEX:g}) | check |\n|---|---|---|---|---|---|---|---|")
    for r in records:
        low, high = r["at_0.1_MPa"], r["at_1_MPa"]

        def cell(point, k):
            return "-" if point is None else f"{point[k]:.3f}"

        print(f"| {r['plies']} | {r['yarn_vf']:g} | {r['relaxed_vf']:.3f} | {cell(low, 0)} | {cell(high, 0)} | "
              f"{cell(low, 1)} / {cell(high, 1)} | {'-' if r['index'] is None else format(r['index'], '.1f')} | "
              f"{'passed' if r['passed'] else 'FAILED'}{'' if r['stopped'] is None else ': ' + r['stopped'][:60]} |")


if __name__ == "__main__":
    main()
