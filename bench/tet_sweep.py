"""The tet mesher on the sweep's fabrics: each solved with the default command plus the tet policy's
least gap (`--min-gap G`, G = 5 % of the thinnest yarn's height), then the corrected model
tet-meshed (meshes/tetra.py, default options), each step in a fresh process. A case counts when
its solve passes its check; it passes when the mesh is made, periodic, with no inverted tet and
every yarn's volume within 1 %. Prints a table and writes JSON:

    python3 bench/tet_sweep.py [--only NAME ...] [--size H] [--out output/tet_sweep.json]
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
from sweep import BUILT, FABRICS, cases  # noqa: E402

GAP_FRACTION = 0.05


def mesh_one(model: str, size: float, out: str) -> None:
    """Tet-mesh one corrected model; its report (or the error) as JSON at `out`."""
    import logging

    from textile_fenicsx.config import load_model
    from textile_fenicsx.meshes.tetra import TetOptions, tet_mesh

    logging.basicConfig(level=logging.INFO, format="%(message)s")
    start, cpu = time.perf_counter(), time.process_time()
    try:
        report = tet_mesh(load_model(model), TetOptions(size=size)).report
    except Exception as e:  # the record says why
        report = {"error": f"{type(e).__name__}: {e}"}
    report["wall_s"], report["cpu_s"] = time.perf_counter() - start, time.process_time() - cpu
    Path(out).write_text(json.dumps(report))


def run_case(name: str, size: float, timeout: float = 1800) -> dict:
    """Solve (with the least gap) and tet-mesh one case in fresh processes; its record."""
    from textile_fenicsx.config import load_model
    from textile_fenicsx.meshes.tetra import thinnest_height

    with tempfile.TemporaryDirectory(prefix=f"tet-{name[:30]}-") as tmp:
        tmp = Path(tmp)
        if name in BUILT:
            built = subprocess.run([sys.executable, "-m", "textile_fenicsx", "build", *BUILT[name], "--no-picture",
                                    "--out", str(tmp / "model")], capture_output=True, text=True, timeout=timeout)
            if built.returncode != 0:
                return {"case": name, "solve": built.returncode, "error": built.stderr.strip().splitlines()[-1:]}
            model = next((tmp / "model").glob("*.tg3"))
        else:
            model = FABRICS / f"{name}.tg3"
        gap = round(GAP_FRACTION * thinnest_height(load_model(model)), 4)
        start = time.perf_counter()
        proc = subprocess.run([sys.executable, "-m", "textile_fenicsx", "solve", str(model), "--seed", "0.5",
                               "--no-figures", "--min-gap", str(gap), "--out", str(tmp / "run")],
                              capture_output=True, text=True, timeout=timeout)
        record = {"case": name, "gap_mm": gap, "solve": proc.returncode, "solve_s": time.perf_counter() - start}
        if proc.returncode != 0:
            record["error"] = proc.stderr.strip().splitlines()[-1:]
            return record
        try:
            subprocess.run([sys.executable, __file__, "--mesh-one", str(tmp / "run" / "corrected.tg3"), "--size",
                            str(size), "--report", str(tmp / "tet.json")], capture_output=True, text=True,
                           timeout=timeout)
            report = json.loads((tmp / "tet.json").read_text())
        except (subprocess.TimeoutExpired, FileNotFoundError, json.JSONDecodeError) as e:
            report = {"error": f"{type(e).__name__}: {e}"}
        record["tet"] = report
        ok = "error" not in report
        if ok:
            ok = (report["periodicity"]["periodic"] and report["inverted_by_gmsh"] >= 0
                  and report["volume"]["worst_error_percent"] < 1.0 and report["smallest_volume_mm3"] > 0)
        record["passed"] = bool(ok)
        return record


def table(records: list[dict]) -> str:
    lines = ["| case | gap mm | solve | tets | minSICN min / mean | worst volume error % | phases off % | "
             "fibre p99 deg | mesh s (cpu) | result |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in records:
        t = r.get("tet", {})
        if "elements" in t:
            yarn = sum(v["model_mm3"] for v in t["volume"]["per_yarn"])
            lines.append(f"| {r['case']} | {r['gap_mm']:.4f} | 0 | {t['elements']} | {t['quality']['min']:.3f} / "
                         f"{t['quality']['mean']:.3f} | {t['volume']['worst_error_percent']:.2f} | "
                         f"{100 * t['phases']['volume'] / yarn:.2f} | {t['fibre_angle_deg']['p99']:.2f} | "
                         f"{t['wall_s']:.0f} ({t['cpu_s']:.0f}) | {'pass' if r['passed'] else 'FAIL'} |")
        else:
            why = t.get("error") or " ".join(r.get("error", []))
            lines.append(f"| {r['case']} | {r.get('gap_mm', 0):.4f} | {r.get('solve')} | | | | | | | "
                         f"{'FAIL: ' if r.get('solve') == 0 else 'solve failed: '}{str(why)[:120]} |")
    solved = [r for r in records if r.get("solve") == 0]
    passed = [r for r in solved if r.get("passed")]
    lines.append(f"\nmeshed {len(passed)} of {len(solved)} solved fabrics ({len(records)} cases)")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--only", nargs="*", help="case names (default: every case)")
    p.add_argument("--size", type=float, default=0.25, help="tet size [mm] (0.25)")
    p.add_argument("--out", default="output/tet_sweep.json")
    p.add_argument("--mesh-one", help=argparse.SUPPRESS)
    p.add_argument("--report", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.mesh_one:
        mesh_one(args.mesh_one, args.size, args.report)
        return 0
    records = []
    for name in args.only or cases():
        records.append(run_case(name, args.size))
        r = records[-1]
        print(name, "solve", r.get("solve"), "passed", r.get("passed"), flush=True)
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(records, indent=1))
    print(table(records))
    return 0


if __name__ == "__main__":
    sys.exit(main())
