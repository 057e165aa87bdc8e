"""The voxel mesh's default rule, measured (issue 72; docs/volume.md, "Voxel sizes").

Two parts, each runnable alone:

    bin/fenicsx-env python3 bench/voxel_rule.py survey [--out output/voxel_survey.json]
    bin/fenicsx-env python3 bench/voxel_rule.py stiffness CASE ... [--ranks 2] [--out output/voxel_rule.json]
    bin/fenicsx-env python3 bench/voxel_rule.py table [--out output/voxel_rule.json]

survey: on every 2D weave of the sweep (reference/fabrics, the 3D weaves left out) and TexGen's
plain, 2/2 twill and 4-harness satin (reference/models), the error of a voxel mesh's yarn fraction
(voxels whose centre lies in a yarn, over the cell) against the model's own (the union of the yarns'
vertical-ray intervals on a 997 x 997 grid), for grids of n voxels across the thinnest yarn's height
and k across the narrowest yarn's width (volume/voxel_sizes.py's rule is n = 8, k = 12); prints
each (n, k)'s worst, 90th percentile and median over the weaves and their voxel counts, and the
same for the default grid (volume.voxel.default_grid: the rule's grid, then the phase search). Mesh
only: a few minutes.

stiffness: CASE is MODEL:NX:NY:NZ[:DEGREE] (MODEL plain, twill22 or satin4 of reference/models; the
voxel counts; the degree of homogenise, default 2). Each runs, as a user does, in fresh processes:

    textile-fenicsx volume-mesh MODEL --kind voxel --size HX HY HZ --out DIR
    textile-fenicsx homogenise DIR/volume.xdmf --no-conduction --degree D --out DIR  (mpirun -n RANKS)

and records the counts, the unknowns, Ex Ez Gxy, the yarn-fraction error, CG iterations, seconds;
a case already in --out is not run again.

table: the converged value of each constant per model, and each case's distance from it. The
second-order sequence does not converge steadily (the grid's phase moves the yarn fraction, and the
constants with it, by percents as the voxels shrink), so Richardson's extrapolation cannot read an
order from it. The converged value is the first-order value on a grid of the default's proportions
m = 2 or 3 times finer per axis, less its own discretisation error there: the first- and
second-order difference on the default grid over m^p, p observed where both orders are on a grid
1.5 x finer (the plain weave), else FE_ORDER; its uncertainty the spread over the m's, else half
the correction. Cases needed per model: MODEL:default:2, MODEL:default:1 and MODEL:m x default:1
(the default from volume.voxel.default_grid).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))
MODELS = REPO / "reference" / "models"
KEYS = ("Ex", "Ez", "Gxy")
# The order of the first-order elements' error on voxels (its difference from second order on one
# grid), where a model's own cases do not show it: measured on the plain weave from the default grid
# and one 1.5 x finer per axis (Ex 1.0, Ez 1.0, Gxy 0.8; docs/volume.md, "Voxel sizes").
FE_ORDER = 1.0


def fraction_error(textile, box, counts: tuple[int, int, int], exact: float) -> float:
    """A grid's yarn-fraction error against the model's `exact` (voxel_sizes.union_fraction) [%]."""
    from textile_fenicsx.volume.voxel import classify

    phase = classify(textile, box, counts)[0]
    return 100 * (float(np.mean(phase > 0)) / exact - 1)


def survey(out: Path, across_height=(4, 6, 8, 12, 16), across_width=(8, 12, 16, 24)) -> None:
    import logging

    from textile_fenicsx.io.config import load_model
    from textile_fenicsx.volume.box import cell_box
    from textile_fenicsx.volume.voxel import default_grid
    from textile_fenicsx.volume.voxel_sizes import union_fraction, yarn_sizes

    logging.disable(logging.WARNING)
    three_d = ("ortho", "l2l", "angleinterlock")
    files = [MODELS / f"{m}.tg3" for m in ("plain", "twill22", "satin4")]
    files += sorted(p for p in (REPO / "reference" / "fabrics").glob("*.tg3") if not p.stem.startswith(three_d))
    records = {}
    for f in files:
        t = load_model(f)
        box = cell_box(t)
        widths, heights = yarn_sizes(t)
        exact = union_fraction(t, box, 997)
        counts, _, search = default_grid(t, box)
        rec: dict = {"width": float(widths.min()), "height": float(heights.min()), "box": box.size.tolist(),
                     "exact": exact, "error": {}, "voxels": {}, "default": list(counts),
                     "default_error": fraction_error(t, box, counts, exact), "default_rule_grid": search["start_grid"],
                     "default_rule_grid_error": fraction_error(t, box, tuple(search["start_grid"]), exact)}
        for n in across_height:
            for k in across_width:
                h = np.array([widths.min() / k, widths.min() / k, heights.min() / n])
                grid = tuple(int(c) for c in np.maximum(np.ceil(box.size / h - 1e-9), 1))
                rec["error"][f"{n},{k}"] = fraction_error(t, box, grid, exact)
                rec["voxels"][f"{n},{k}"] = int(np.prod(grid))
        records[f.stem] = rec
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(records, indent=1))  # each weave as it ends
        print(f.stem, " ".join(f"{key}:{e:+.1f}" for key, e in rec["error"].items()),
              f"default {counts} {rec['default_error']:+.2f} (rule's grid {rec['default_rule_grid_error']:+.2f})",
              flush=True)
    print(f"\nyarn-fraction error over {len(records)} 2D weaves, n across the thinnest height, k across the "
          "narrowest width")
    print("| n | k | worst % | (weave) | 90th percentile % | median % | voxels: median | largest |")
    print("|---|---|---|---|---|---|---|---|")
    for key in next(iter(records.values()))["error"]:
        e = np.array([abs(r["error"][key]) for r in records.values()])
        v = np.array([r["voxels"][key] for r in records.values()])
        worst = max(records, key=lambda m: abs(records[m]["error"][key]))
        n, k = key.split(",")
        print(f"| {n} | {k} | {e.max():.1f} | {worst} | {np.percentile(e, 90):.1f} | {np.median(e):.1f} | "
              f"{int(np.median(v))} | {v.max()} |")
    for which, label in (("default_rule_grid", "the rule's grid (8, 12, capped at DEFAULT_MAX_VOXELS)"),
                         ("default", "the default (the rule's grid, then the phase search)")):
        e = np.array([abs(r[which + "_error"]) for r in records.values()])
        v = np.array([np.prod(r[which]) for r in records.values()])
        worst = max(records, key=lambda m: abs(records[m][which + "_error"]))
        print(f"{label}: worst {e.max():.2f} % ({worst}), 90th percentile {np.percentile(e, 90):.2f} %, median "
              f"{np.median(e):.2f} %; voxels median {int(np.median(v))}, largest {v.max()}")


def stiffness(cases: list[str], ranks: int, out: Path) -> None:
    import logging
    import tempfile

    from volume_bench import timed

    from textile_fenicsx.io.config import load_model
    from textile_fenicsx.volume.box import cell_box
    from textile_fenicsx.volume.voxel_sizes import union_fraction

    logging.disable(logging.WARNING)
    records = json.loads(out.read_text()) if out.exists() else {}
    for case in cases:
        name, nx, ny, nz, *degree = case.split(":")
        key = f"{name}:{nx}:{ny}:{nz}:q{degree[0] if degree else 2}"
        if key in records:
            continue
        model = MODELS / f"{name}.tg3"
        t = load_model(model)
        box = cell_box(t)
        counts = (int(nx), int(ny), int(nz))
        sizes = [repr(float(v)) for v in box.size / np.array(counts)]
        with tempfile.TemporaryDirectory(prefix="voxel-rule-") as tmp:
            folder = Path(tmp)
            mesh = timed(["volume-mesh", str(model), "--kind", "voxel", "--size", *sizes, "--force", "--out",
                          str(folder)])
            homog = timed(["homogenise", str(folder / "volume.xdmf"), "--no-conduction", "--degree",
                           degree[0] if degree else "2", "--out", str(folder)], ranks)
            report = json.loads((folder / "mesh_report.json").read_text())
            s = json.loads((folder / "stiffness.json").read_text())

        assert report["voxels"] == list(counts), (report["voxels"], counts)
        records[key] = {"voxels": report["voxels"], "voxel_mm": report["sizes"]["voxel_mm"],
                        "fraction_error": fraction_error(t, box, counts, union_fraction(t, box, 997)),
                        "dofs": s["dofs"]["elasticity"], "iterations": s["iterations"]["elasticity"],
                        "constants": s["engineering_constants"], "vf": s["fibre_volume_fraction"],
                        "mesh_s": mesh["seconds"], "homogenise_s": homog["seconds"],
                        "homogenise_cpu_s": homog["cpu_seconds"], "peak_gb": homog["peak_gb"], "ranks": ranks}
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(records, indent=1))
        c = s["engineering_constants"]
        print(key, s["dofs"]["elasticity"], " ".join(f"{k} {c[k]:.0f}" for k in KEYS),
              f"{homog['seconds']:.0f} s", flush=True)


def converged(cases: dict, key: str, default: tuple[int, int, int]) -> dict:
    """The converged value of constant `key` from one model's cases (module docstring): the first-order
    value on the finest grid of the default one's proportions at least twice as fine (m times), less
    its discretisation error there, the first- and second-order difference on the default grid over
    m^p; p is observed where both orders are on a finer grid of those proportions too, else FE_ORDER.
    The uncertainty: the spread of such values over the grids at least twice as fine, else half the
    correction."""
    def ratio(counts: list[int]) -> float | None:
        r = np.array(counts) / np.array(default)
        return float(r.mean()) if np.ptp(r) < 0.05 * r.mean() else None  # one ratio on every axis

    first, second = {}, {}
    for k, v in cases.items():
        r = ratio(v["voxels"])
        if r is not None:
            (first if k.endswith(":q1") else second)[r] = v["constants"][key]
    if 1.0 not in first or 1.0 not in second or not any(r >= 1.9 for r in first):
        return {"value": None}
    gap = first[1.0] - second[1.0]
    order, observed = FE_ORDER, False
    for r in sorted(set(first) & set(second)):
        other = first[r] - second[r]
        if r > 1.2 and gap * other > 0 and abs(other) < abs(gap):
            order, observed = float(np.log(gap / other) / np.log(r)), True
    values = {r: first[r] - gap / r**order for r in first if r >= 1.9}
    m = max(values)
    spread = max(values.values()) - min(values.values()) if len(values) > 1 else abs(gap) / m**order / 2
    return {"value": values[m], "order": order, "observed": observed, "multiple": m, "uncertainty": spread,
            "correction": -gap / m**order}


def table(out: Path) -> None:
    import logging

    from textile_fenicsx.io.config import load_model
    from textile_fenicsx.volume.box import cell_box
    from textile_fenicsx.volume.voxel import default_grid
    from textile_fenicsx.volume.voxel_sizes import ACROSS_HEIGHT

    logging.disable(logging.WARNING)
    records = json.loads(out.read_text())
    for name in sorted({k.split(":")[0] for k in records}):
        mine = {k: v for k, v in records.items() if k.startswith(name + ":")}
        t = load_model(MODELS / f"{name}.tg3")
        box = cell_box(t)
        default, rule, _ = default_grid(t, box)
        conv = {key: converged(mine, key, default) for key in KEYS}
        if any(c["value"] is None for c in conv.values()):
            print(f"\n{name}: no reference (first and second order on the default grid {default}, first order "
                  "on a multiple of it)")
            continue
        print(f"\n{name} (default {' x '.join(map(str, default))}): converged " + ", ".join(
            f"{k} {c['value']:.0f} MPa +-{c['uncertainty']:.0f} (Q1 on {c['multiple']:.2g}x the default grid "
            f"{c['correction']:+.0f}, order {c['order']:.2f}{' observed' if c['observed'] else ''})"
            for k, c in conv.items()))
        print("| voxels | mm | voxels across the height | degree | unknowns | CG its | yarn fraction % | " +
              " | ".join(f"{k} MPa (%)" for k in KEYS) + " | homogenise s (CPU s) |")
        print("|---|---|---|---|---|---|---|" + "---|" * len(KEYS) + "---|")
        for k, r in sorted(mine.items(), key=lambda kv: (kv[0].split(":")[-1], kv[1]["dofs"])):
            c = r["constants"]
            cells = " | ".join(f"{c[q]:.0f} ({100 * (c[q] / conv[q]['value'] - 1):+.1f})" for q in KEYS)
            across = float(rule.heights.min()) / r["voxel_mm"][2]
            print(f"| {' x '.join(map(str, r['voxels']))} | {' x '.join(f'{h:.3g}' for h in r['voxel_mm'])} | "
                  f"{across:.1f} (rule {ACROSS_HEIGHT}) | {k[-1]} | {r['dofs']} | "
                  f"{min(r['iterations'])}-{max(r['iterations'])} | {r['fraction_error']:+.2f} | {cells} | "
                  f"{r['homogenise_s']:.0f} ({r['homogenise_cpu_s']:.0f}) |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("part", choices=["survey", "stiffness", "table"])
    parser.add_argument("cases", nargs="*", help="stiffness: MODEL:NX:NY:NZ[:DEGREE]")
    parser.add_argument("--ranks", type=int, default=2)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    if args.part == "survey":
        survey(args.out or REPO / "output" / "voxel_survey.json")
    elif args.part == "stiffness":
        stiffness(args.cases, args.ranks, args.out or REPO / "output" / "voxel_rule.json")
    else:
        table(args.out or REPO / "output" / "voxel_rule.json")


if __name__ == "__main__":
    main()
