"""The robustness sweep: the default command on a family of fabrics users bring.

Every fabric of reference/fabrics/ (built with TexGen's own classes: 2D weaves loose to jammed,
every section type, rectangular cells, unbalanced yarns, refine on and off; TexGen stacks of plies
(CTextileLayered) at any offset and mixed; orthogonal,
layer-to-layer and angle-interlock 3D weaves) and a few of our own builders' fabrics, each solved
by `textile-fenicsx solve FILE --seed SEED --no-figures --out DIR` in a fresh process, as a user
runs it. A case passes when the command exits 0: the contact solve converged and the corrected
model passed its check (verify.py: overlap <= 1 % of before, depth <= 1 % of the thinnest yarn,
volumes and section areas within 1 %, no crossed section). tests/test_sweep.py runs it (marked
slow); `make sweep` prints the table:

    python3 bench/sweep.py [--seed 0.5] [--only NAME ...] [--out output/sweep.json]

With --compaction K --vf V (`make sweep-compaction`: K 50 MPa, Vf 0.5) every 2D fabric is solved
and then pressed to Vf V (docs/compaction.md); the 3D weaves are left out (their binder legs are
not plates: compaction refuses them). --spreading S lets the pressed yarns spread (spreading.py).
"""

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
FABRICS = REPO / "reference" / "fabrics"
# our builders, by name: (builder arguments for `textile-fenicsx build`)
BUILT = {
    "ours_plain_jammed": ["plain", "--spacing", "2", "--width", "1.96", "--height", "0.4"],
    "ours_twill_loose": ["twill", "--spacing", "2", "--width", "1.2", "--height", "0.24"],
    "ours_satin5": ["satin", "--harness", "5", "--move", "2", "--spacing", "2", "--width", "1.8", "--height", "0.36"],
    "ours_orthogonal": ["orthogonal"],
}


THREE_D = ("ortho", "l2l", "angleinterlock", "ours_orthogonal")


def cases(two_d: bool = False) -> list[str]:
    """Every case name: the fabric files' stems, then our builders' (two_d: the 2D weaves only)."""
    names = sorted(p.stem for p in FABRICS.glob("*.tg3")) + sorted(BUILT)
    return [n for n in names if not n.startswith(THREE_D)] if two_d else names


def run_case(name: str, seed: float = 0.5, timeout: float = 900, ranks: int = 1, keep: Path | None = None,
             extra: tuple[str, ...] = ()) -> dict:
    """Solve one case with the default command in a fresh process (under mpirun -n ranks if > 1);
    its record. keep: a folder to which the run's model files and metrics.json are copied (as
    keep/name/). extra: more arguments of the solve (the compaction's)."""
    with tempfile.TemporaryDirectory(prefix=f"sweep-{name[:30]}-") as tmp:
        tmp = Path(tmp)
        if name in BUILT:
            built = subprocess.run([sys.executable, "-m", "textile_fenicsx", "build", *BUILT[name], "--no-picture",
                                    "--out", str(tmp / "model")], capture_output=True, text=True, timeout=timeout)
            if built.returncode != 0:
                return {"case": name, "exit": built.returncode, "error": built.stderr.strip().splitlines()[-1:]}
            model = next((tmp / "model").glob("*.tg3"))
        else:
            model = FABRICS / f"{name}.tg3"
        out = tmp / "run"
        start = time.perf_counter()
        mpi = ["mpirun", "-n", str(ranks)] if ranks > 1 else []
        proc = subprocess.run([*mpi, sys.executable, "-m", "textile_fenicsx", "solve", str(model), "--seed", str(seed),
                               "--no-figures", "--out", str(out), *extra], capture_output=True, text=True,
                              timeout=timeout)
        record = {"case": name, "seed": seed, "ranks": ranks, "exit": proc.returncode,
                  "seconds": time.perf_counter() - start}
        metrics = out / "metrics.json"
        if metrics.is_file():
            m = json.loads(metrics.read_text())
            before, after = m["interpenetration"]["before"], m["interpenetration"]["after"]
            record.update(dofs=m["dofs"], iterations=m["iterations"], passed=m["verdict"]["passed"],
                          overlap_before=before["volume"], overlap_after=after["volume"],
                          depth_before=before["max_depth"], depth_after=after["max_depth"],
                          thickness_before=m["thickness"]["before"], thickness_after=m["thickness"]["after"],
                          volume_change=max(map(abs, m["yarn_volume_change"])), vf=m["vf"],
                          failures=[f["message"] for f in m["verdict"]["failures"]],
                          meshed_at=m["mesh"]["seed"])  # the seed of the run kept (Settings.remesh)
        if (out / "compaction.json").is_file():
            curve = json.loads((out / "compaction.json").read_text())
            record.update(width_factors=m["compaction"]["width_factors"] if metrics.is_file() else None,
                          pressure=curve["pressure"][-1], relaxed=curve["thickness"][0], pressed=curve["thickness"][-1],
                          densest=max(curve["densest"]), compaction_reason=curve["reason"],
                          compaction_newton_steps=sum(curve["iterations"]), imbalance=max(curve["imbalance"]))
        if proc.returncode != 0:
            record["error"] = proc.stderr.strip().splitlines()[-1:] if proc.stderr.strip() else []
        if keep is not None and out.is_dir():
            (keep / name).mkdir(parents=True, exist_ok=True)
            for f in ("corrected.tg3", "rejected.tg3", "metrics.json"):
                if (out / f).is_file():
                    shutil.copy(out / f, keep / name / f)
            if name in BUILT:
                shutil.copy(model, keep / name / "model.tg3")
        return record


def _case(r: dict) -> str:
    """The case's name, with the seed it was meshed again at where its corrected yarns overlapped."""
    again = r.get("meshed_at", r.get("seed"))
    return r["case"] if again == r.get("seed") else f"{r['case']} (at {again:g})"


def table(records: list[dict]) -> str:
    """A markdown table of the records, with the pass rate."""
    lines = ["| case | exit | dofs | steps | overlap mm^3 before -> after | depth mm before -> after | "
             "thickness mm | max volume change | s |", "|---|---|---|---|---|---|---|---|---|"]
    for r in records:
        if "overlap_before" in r:
            lines.append(f"| {_case(r)} | {r['exit']} | {r['dofs']} | {r['iterations']} | "
                         f"{r['overlap_before']:.4f} -> {r['overlap_after']:.2e} | {r['depth_before']:.4f} -> "
                         f"{r['depth_after']:.4f} | {r['thickness_before']:.3f} -> {r['thickness_after']:.3f} | "
                         f"{100 * r['volume_change']:.2f} % | {r['seconds']:.0f} |")
        else:
            lines.append(f"| {r['case']} | {r['exit']} | | | {' '.join(r.get('error', []))[:120]} | | | | "
                         f"{r.get('seconds', 0):.0f} |")
    passed = sum(r["exit"] == 0 for r in records)
    lines.append(f"\npassed {passed} of {len(records)} ({100 * passed / max(len(records), 1):.0f} %)")
    return "\n".join(lines)


def _spread(widths: list | None) -> str:
    """The width factors of a run whose yarns spread: their range, or - where none spread."""
    return "-" if not widths else f"{min(widths):.3f}-{max(widths):.3f}"


def compaction_table(records: list[dict]) -> str:
    """The compaction's numbers per case: relaxed and pressed thickness, Vf, pressure, densest yarn,
    the compaction's Newton steps (its steps and the last one's re-solve) and the largest imbalance
    of its forces when a step settled (solver/newton.py, DUAL_RTOL)."""
    lines = ["| case | exit | relaxed mm | pressed mm | Vf after (rays) | pressure MPa | densest phi | Newton | "
             "imbalance | spread | stopped |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in records:
        if "pressure" in r:
            vf = r["vf"]["after"] if r.get("vf") and r["vf"]["after"] is not None else float("nan")
            lines.append(f"| {_case(r)} | {r['exit']} | {r['relaxed']:.3f} | {r['pressed']:.3f} | {vf:.3f} | "
                         f"{r['pressure']:.3g} | {r['densest']:.3f} | {r['compaction_newton_steps']} | "
                         f"{r['imbalance']:.0e} | {_spread(r.get('width_factors'))} | "
                         f"{(r['compaction_reason'] or '')[:80]} |")
        else:
            lines.append(f"| {r['case']} | {r['exit']} | | | | | | | | | {' '.join(r.get('error', []))[:80]} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seed", type=float, default=0.5)
    parser.add_argument("--only", nargs="+", metavar="NAME")
    parser.add_argument("--ranks", type=int, default=1, help="MPI ranks per solve (mpirun -n)")
    parser.add_argument("--out", type=Path, default=REPO / "output" / "sweep.json")
    parser.add_argument("--keep", type=Path, help="copy each run's model files and metrics.json to KEEP/NAME/")
    parser.add_argument("--compaction", type=float, metavar="K", help="press each 2D fabric (K: k E_f [MPa])")
    parser.add_argument("--vf", type=float, default=0.5, help="with --compaction: the target Vf (0.5)")
    parser.add_argument("--spreading", type=float, default=0.0, help="with --compaction: the width spreading "
                        "exponent S (0: widths kept)")
    args = parser.parse_args()
    extra = () if args.compaction is None else ("--compaction", str(args.compaction), "--vf", str(args.vf),
                                                "--spreading", str(args.spreading))
    records = []
    for name in args.only or cases(two_d=args.compaction is not None):
        print(f"sweep: {name}", file=sys.stderr, flush=True)
        records.append(run_case(name, args.seed, ranks=args.ranks, keep=args.keep, extra=extra))
        r = records[-1]
        print(f"sweep: {name}: exit {r['exit']}" + (f", {r['failures']}" if r.get("failures") else "")
              + (f", {r['error']}" if r.get("error") and not r.get("failures") else ""), file=sys.stderr, flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"machine": os.uname().nodename, "records": records}, indent=1))
    print(table(records))
    if args.compaction is not None:
        print(compaction_table(records))


if __name__ == "__main__":
    main()
