"""The flow solver against the drag's contrast (make bench-flow): iterations of the iterative solve
(flow/problem.py ITERATIVE) and its K against the direct solve's, for yarns from nearly free to
impermeable, on the corrected satin4's voxel cells.

    python3 bench/flow_contrast.py [--sizes 0.6 0.3] [--out output/flow_contrast.json]

The contrast is the yarns' drag against the pores' viscous scale: (1 / K_yarn) / (1 / h^2), h the
voxel size. The satin is corrected at seed 0.5 by the default command, then meshed as voxels of each
size; every row solves the same mesh once by FGMRES and once by MUMPS (where it fits).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from mpi4py import MPI

REPO = Path(__file__).resolve().parents[1]
MODEL = REPO / "reference" / "models" / "satin4.tg3"
# the yarns: isotropic permeabilities [m^2], Gebart's laws (carbon, r = 3.5 um) and solid
YARNS: list = [1e-8, 1e-10, 1e-12, 1e-14, "gebart", "impermeable"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", nargs="+", type=float, default=[0.6, 0.3])
    parser.add_argument("--out", type=Path, default=REPO / "output" / "flow_contrast.json")
    args = parser.parse_args()
    from textile_fenicsx.flow.effective import PermeabilityOptions, permeability
    from textile_fenicsx.volume.files import read_volume

    rows = []
    with tempfile.TemporaryDirectory(prefix="flow-contrast-") as tmp:
        folder = Path(tmp)
        cli = [sys.executable, "-m", "textile_fenicsx"]
        subprocess.run([*cli, "solve", str(MODEL), "--seed", "0.5", "--no-figures", "--out", str(folder / "satin")],
                       check=True, capture_output=True)
        for size in args.sizes:
            mesh = folder / f"voxel_{size}"
            subprocess.run([*cli, "volume-mesh", str(folder / "satin" / "corrected.tg3"), "--kind", "voxel", "--size",
                            str(size), "--out", str(mesh)], check=True, capture_output=True)
            fields = read_volume(mesh / "volume.xdmf", MPI.COMM_WORLD)
            for yarns in YARNS:
                row: dict = {"size_mm": size, "yarns": yarns}
                for solver in ("iterative", "direct"):
                    t0 = time.perf_counter()
                    result = permeability(fields, PermeabilityOptions(yarns=yarns, fibre_radius=0.0035, solver=solver,
                                                                      memory_limit=16))
                    row[solver] = {"seconds": time.perf_counter() - t0, "iterations": result.options["iterations"],
                                   "K_m2": result.K_m2.tolist(), "dofs": result.dofs}
                K_direct = np.array(row["direct"]["K_m2"])
                row["difference"] = float(np.abs(np.array(row["iterative"]["K_m2"]) - K_direct).max()
                                          / np.abs(K_direct).max())
                rows.append(row)
                print(f"voxel {size} mm, yarns {yarns}: {row['iterative']['iterations']} iterations, "
                      f"{row['iterative']['seconds']:.1f} s (direct {row['direct']['seconds']:.1f} s), "
                      f"K within {row['difference']:.1e}", file=sys.stderr, flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(rows, indent=1))
    print("| voxel mm | dofs | yarns | contrast (h^2 / K_yarn) | FGMRES iterations (x, y, z) | iterative s | "
          "direct s | max |K_it - K_direct| / max |K| |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        contrast = (f"{(r['size_mm'] * 1e-3) ** 2 / r['yarns']:.0e}" if isinstance(r["yarns"], float) else
                    "Gebart's (about 1e7 across)" if r["yarns"] == "gebart" else "solid yarns")
        print(f"| {r['size_mm']:g} | {r['iterative']['dofs']} | {r['yarns']} | {contrast} | "
              f"{'/'.join(map(str, r['iterative']['iterations']))} | {r['iterative']['seconds']:.1f} | "
              f"{r['direct']['seconds']:.1f} | {r['difference']:.1e} |")


if __name__ == "__main__":
    main()
