"""The permeability over the sweep's 2D weaves (make sweep-flow): each fabric corrected by the default
command (bench/sweep.py's run_case), its corrected.tg3 meshed as voxels, and its permeability, each
step a command in a fresh process as a user runs it:

    textile-fenicsx solve FABRIC --seed 0.5 --no-figures --out DIR
    textile-fenicsx volume-mesh DIR/corrected.tg3 --kind voxel --size H --layers L --out DIR/vox
    textile-fenicsx permeability DIR/vox/volume.xdmf --fibre-radius R --out DIR/flow

    python3 bench/flow_sweep.py [--size 0.3] [--layers 4] [--only NAME ...] [--out output/flow_sweep.json]

A case passes when every command exits 0 and K is symmetric (to 1e-6 of its largest entry) and
positive definite. The table gives K's diagonal at the relaxed fabric's Vf (the voxels' own: the
yarns' volume over the cell's), its porosity, the unknowns and the seconds of the permeability.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from sweep import cases, run_case  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def flow_case(name: str, size: float, layers: int, radius: float, timeout: float = 1800) -> dict:
    """One fabric through solve, volume-mesh and permeability; its record."""
    cli = [sys.executable, "-m", "textile_fenicsx"]
    with tempfile.TemporaryDirectory(prefix=f"flow-{name[:30]}-") as tmp:
        keep = Path(tmp)
        record = {"case": name, "solve": run_case(name, keep=keep)}
        corrected = keep / name / "corrected.tg3"
        if record["solve"]["exit"] != 0 or not corrected.is_file():
            return {**record, "exit": record["solve"]["exit"], "stage": "solve"}
        for stage, command in (("volume-mesh", ["volume-mesh", str(corrected), "--kind", "voxel", "--size", str(size),
                                                "--layers", str(layers), "--out", str(keep / "vox")]),
                               ("permeability", ["permeability", str(keep / "vox" / "volume.xdmf"), "--fibre-radius",
                                                 str(radius), "--out", str(keep / "flow")])):
            start = time.perf_counter()
            proc = subprocess.run([*cli, *command], capture_output=True, text=True, timeout=timeout)
            record[f"{stage}_s"] = time.perf_counter() - start
            if proc.returncode != 0:
                return {**record, "exit": proc.returncode, "stage": stage,
                        "error": proc.stderr.strip().splitlines()[-1:]}
        doc = json.loads((keep / "flow" / "permeability.json").read_text())
        ok = doc["checks"]["asymmetry"] < 1e-6 and doc["checks"]["positive_definite"]
        return {**record, "exit": 0, "passed": ok, "K_m2": doc["K_m2"], "vf": doc["vf"], "porosity": doc["porosity"],
                "dofs": doc["dofs"], "iterations": doc["options"]["iterations"], "checks": doc["checks"]}


def table(records: list[dict]) -> str:
    lines = ["| case | Vf | porosity | Kxx m^2 | Kyy m^2 | Kzz m^2 | dofs | permeability s | passed |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in records:
        if r["exit"] == 0:
            K, verdict = r["K_m2"], "yes" if r["passed"] else "NO"
            lines.append(f"| {r['case']} | {r['vf']:.3f} | {r['porosity']:.3f} | {K[0][0]:.3e} | {K[1][1]:.3e} | "
                         f"{K[2][2]:.3e} | {r['dofs']} | {r['permeability_s']:.0f} | {verdict} |")
        else:
            lines.append(f"| {r['case']} | | | | | | | | {r['stage']} exit {r['exit']}: "
                         f"{' '.join(r.get('error', []))[:100]} |")
    passed = sum(r["exit"] == 0 and r["passed"] for r in records)
    lines.append(f"\npassed {passed} of {len(records)}")
    done = [r for r in records if r["exit"] == 0]
    if done:
        low = min(done, key=lambda r: min(r["K_m2"][i][i] for i in range(3)))
        slow = max(done, key=lambda r: r["permeability_s"])
        lines.append(f"lowest K: {low['case']} (Kzz {low['K_m2'][2][2]:.3e} m^2); slowest: {slow['case']} "
                     f"({slow['permeability_s']:.0f} s, {slow['dofs']} unknowns)")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--size", type=float, default=0.3, help="voxel size in plane [mm]")
    parser.add_argument("--layers", type=int, default=4, help="voxels through the thickness")
    parser.add_argument("--fibre-radius", type=float, default=0.0035, help="[mm]")
    parser.add_argument("--only", nargs="+", help="these cases only")
    parser.add_argument("--out", type=Path, default=REPO / "output" / "flow_sweep.json")
    args = parser.parse_args()
    names = args.only or cases(two_d=True)
    records = []
    for k, name in enumerate(names):
        print(f"flow sweep {k + 1}/{len(names)}: {name}", file=sys.stderr, flush=True)
        records.append(flow_case(name, args.size, args.layers, args.fibre_radius))
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({"size": args.size, "layers": args.layers, "records": records}, indent=1))
    print(table(records))


if __name__ == "__main__":
    main()
