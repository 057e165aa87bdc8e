"""The volume stage over the sweep's fabric family: voxel and tet meshes, and their homogenisation.

For every case of the robustness sweep (bench/sweep.py: reference/fabrics and our builders'), each
command in a fresh process as a user runs it:

1. `volume-mesh INPUT --kind voxel` on the idealised input (its overlap counted);
2. `solve INPUT --seed 0.5 --min-gap G --out DIR`: the default solve with the tet mesher's gap held
   (G: 5 % of the thinnest yarn's height, as `solve --volume-mesh tet` takes it), then, when the
   solve passes its check, `volume-mesh DIR/corrected.tg3 --kind tet --gap G` (at most 30 minutes);
3. `volume-mesh DIR/corrected.tg3 --kind voxel`, then `homogenise` of it (first-order elements, to
   keep the family's run short; the bench and the demo use second order). Sizes 0.25 mm (voxel) and
   0.35 mm (tet) by default, coarser than the bench's, to keep 53 fabrics to a few hours.

    python3 bench/volume_sweep.py [--only NAME ...] [--voxel 0.25] [--tet 0.35] [--out output/volume_sweep.json]
                                  [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import sweep  # noqa: E402

from textile_fenicsx.io.config import load_model as read_model  # noqa: E402
from textile_fenicsx.volume.tet.options import TetOptions, default_gap  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
# s: a tet mesh not made by then counts as failed (3D weaves take 6-14 min; retracing their sections, 2-3 x that)
TET_TIMEOUT = 1800


def command(*args: str, timeout: float = 1800) -> tuple[int, str, float]:
    """textile-fenicsx ARGS in a fresh process: (exit code, the last line of stderr, seconds)."""
    start = time.perf_counter()
    try:
        proc = subprocess.run([sys.executable, "-m", "textile_fenicsx", *args], capture_output=True, text=True,
                              timeout=timeout)
    except subprocess.TimeoutExpired:
        return -1, f"timed out after {timeout:.0f} s", time.perf_counter() - start
    lines = [line for line in proc.stderr.strip().splitlines() if "error" in line] or proc.stderr.strip().splitlines()
    return proc.returncode, (lines[-1] if lines and proc.returncode else ""), time.perf_counter() - start


def _mesh_record(folder: Path) -> dict:
    r = json.loads((folder / "mesh_report.json").read_text())
    errors = [abs(y["relative_error"]) for y in r["yarns"] if y["relative_error"] is not None]
    return {"elements": r["elements"], "worst_volume_error": max(errors, default=0.0),
            "quality_min": r["quality"]["min"], "overlap_voxels": r.get("overlap", {}).get("voxels", 0),
            "overlap_volume": r.get("overlap", {}).get("volume", 0.0), "periodic": r["periodicity"]["periodic"]}


def _keep(folder: Path, keep: Path | None, name: str, prefix: str = "") -> None:
    """Copy the run's corrected model, metrics and mesh report to keep/name/ (to re-mesh a failure
    without solving again; a mesh's report as prefix + mesh_report.json)."""
    if keep is None or not folder.is_dir():
        return
    (keep / name).mkdir(parents=True, exist_ok=True)
    for f in ("corrected.tg3", "metrics.json", "mesh_report.json"):
        if (folder / f).is_file():
            shutil.copy(folder / f, keep / name / (prefix + f))


def run_case(name: str, voxel: float, tet: float, keep: Path | None = None) -> dict:
    record: dict = {"case": name}
    with tempfile.TemporaryDirectory(prefix=f"vsweep-{name[:30]}-") as tmp:
        tmp = Path(tmp)
        if name in sweep.BUILT:
            code, err, _ = command("build", *sweep.BUILT[name], "--no-picture", "--out", str(tmp / "model"))
            if code:
                return {**record, "error": err}
            model = next((tmp / "model").glob("*.tg3"))
        else:
            model = sweep.FABRICS / f"{name}.tg3"
        code, err, sec = command("volume-mesh", str(model), "--kind", "voxel", "--size", str(voxel), "--out",
                                 str(tmp / "ideal"))
        record["ideal_voxel"] = {"exit": code, "error": err, "seconds": sec,
                                 **(_mesh_record(tmp / "ideal") if code == 0 else {})}
        gap = default_gap(read_model(model), TetOptions())
        code, err, sec = command("solve", str(model), "--seed", "0.5", "--no-figures", "--min-gap", f"{gap:.6g}",
                                 "--out", str(tmp / "run"))
        metrics = tmp / "run" / "metrics.json"
        passed = metrics.is_file() and json.loads(metrics.read_text())["verdict"]["passed"]
        record["solve"] = {"exit": code, "passed": passed, "seconds": sec, "gap": gap}
        if passed:
            code, err, sec = command("volume-mesh", str(tmp / "run" / "corrected.tg3"), "--kind", "tet", "--size",
                                     str(tet), "--gap", f"{gap:.6g}", "--out", str(tmp / "tet"), timeout=TET_TIMEOUT)
            record["tet"] = {"exit": code, "error": err, "seconds": sec,
                             **(_mesh_record(tmp / "tet") if code == 0 else {})}
            _keep(tmp / "tet", keep, name, "tet_")
            code, err, sec = command("volume-mesh", str(tmp / "run" / "corrected.tg3"), "--kind", "voxel", "--size",
                                     str(voxel), "--out", str(tmp / "voxel"))
            record["voxel"] = {"exit": code, "error": err, "seconds": sec,
                               **(_mesh_record(tmp / "voxel") if code == 0 else {})}
            if code == 0:
                code, err, sec = command("homogenise", str(tmp / "voxel" / "volume.xdmf"), "--degree", "1", "--out",
                                         str(tmp / "voxel"))
                record["homogenise"] = {"exit": code, "error": err, "seconds": sec}
                if code == 0:
                    s = json.loads((tmp / "voxel" / "stiffness.json").read_text())
                    c = s["engineering_constants"]
                    record["homogenise"].update(Ex=c["Ex"], Ey=c["Ey"], vf=s["fibre_volume_fraction"],
                                                checks=s["checks"])
        else:
            record["solve"]["error"] = err
        _keep(tmp / "run", keep, name)
    return record


def table(records: list[dict]) -> str:
    def cell(r: dict | None, key: str = "elements") -> str:
        if r is None:
            return "-"
        return f"{r[key]}" if r["exit"] == 0 else f"exit {r['exit']}: {r['error'][:60]}"

    lines = ["| case | voxel, idealised (overlap voxels) | solve | tet (quality min, volume error) | "
             "voxel, corrected (volume error) | homogenised Ex MPa (Vf) |", "|---|---|---|---|---|---|"]
    for r in records:
        iv, tet, vox, h = r.get("ideal_voxel"), r.get("tet"), r.get("voxel"), r.get("homogenise")
        ideal = cell(iv) + (f" ({iv['overlap_voxels']})" if iv and iv["exit"] == 0 else "")
        solve = "passed" if r.get("solve", {}).get("passed") else f"fails ({r.get('solve', {}).get('exit')})"
        tets = cell(tet) + (f" ({tet['quality_min']:.3f}, {100 * tet['worst_volume_error']:.2f} %)"
                            if tet and tet["exit"] == 0 else "")
        homog = f"{h['Ex']:.0f} ({h['vf']:.3f})" if h and h["exit"] == 0 else cell(h)
        voxels = cell(vox) + (f" ({100 * vox['worst_volume_error']:.1f} %)" if vox and vox["exit"] == 0 else "")
        lines.append(f"| {r['case']} | {ideal} | {solve} | {tets} | {voxels} | {homog} |")
    ideal_ok = sum(r.get("ideal_voxel", {}).get("exit") == 0 for r in records)
    solved = [r for r in records if r.get("solve", {}).get("passed")]
    tet_ok = sum(r.get("tet", {}).get("exit") == 0 for r in solved)
    vox_ok = sum(r.get("voxel", {}).get("exit") == 0 for r in solved)
    homog_ok = sum(r.get("homogenise", {}).get("exit") == 0 for r in solved)
    lines.append(f"\nvoxel on the idealised inputs: {ideal_ok} of {len(records)}; of the {len(solved)} fabrics whose "
                 f"solve (with the gap) passes its check: tet {tet_ok}, voxel {vox_ok}, homogenised {homog_ok}")
    return "\n".join(lines)


THREE_D = ("angleinterlock", "l2l", "ortho", "ours_orthogonal")  # run last: the slowest


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--only", nargs="+", metavar="NAME")
    parser.add_argument("--voxel", type=float, default=0.25, help="voxel size [mm]")
    parser.add_argument("--tet", type=float, default=0.35, help="tet size [mm]")
    parser.add_argument("--out", type=Path, default=REPO / "output" / "volume_sweep.json")
    parser.add_argument("--keep", type=Path, help="copy each solve's corrected.tg3, metrics.json and mesh_report.json "
                        "to KEEP/NAME/")
    args = parser.parse_args()
    records = []
    for name in args.only or sorted(sweep.cases(), key=lambda n: n.startswith(THREE_D)):
        print(f"volume sweep: {name}", file=sys.stderr, flush=True)
        records.append(run_case(name, args.voxel, args.tet, args.keep))
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({"machine": os.uname().nodename, "records": records}, indent=1))
    print(table(records))


if __name__ == "__main__":
    main()
