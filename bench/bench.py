"""`make bench`: the pipeline stage by stage on the issue's cases, serial and on 2 ranks.

Each case runs in its own process (under `mpirun -n R` for R ranks) after a warm-up process has
filled the form cache, and reports seconds per stage, dofs, iterations and memory (peak resident
set size per rank, summed over the ranks; after each stage; and each stage's own peak, sampled
every 20 ms, as the largest rank's and summed over the ranks). The driver prints a table and
writes every number to JSON (default output/bench.json).

Stages: model (read the .tg3 / build and tile), mesh (gmsh + transfer), midsurfaces (sampling and
coupling structure), assemble (plate matrices, maps), solve (contact iteration), correct (corrected
yarns), metrics (before/after on a 200 x 200 ray grid), export (corrected.tg3, corrected.json,
initial.json, metrics.json). end_to_end = their sum: input file to corrected model and metrics,
no fields, surfaces or figures. extras: the fields and surfaces of a full output folder, timed apart.

    python3 bench/bench.py [--quick] [--out FILE] [--only NAME ...]
    python3 bench/bench.py --case NAME   (one case in this process; what the driver runs)
"""

import argparse
import json
import os
import resource
import subprocess
import sys
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SATIN = REPO / "reference" / "models" / "satin4.tg3"

# name: (model, seed, repeats (nx, ny[, "free": free edges]), method, ranks)
CASES = {
    "satin4 1.0": ("satin4", 1.0, None, "exact", (1, 2)),
    "satin4 0.5": ("satin4", 0.5, None, "exact", (1, 2)),
    "satin4 0.25": ("satin4", 0.25, None, "exact", (1, 2)),
    "satin4 0.125": ("satin4", 0.125, None, "exact", (1, 2)),
    "satin4 0.25 penalty": ("satin4", 0.25, None, "penalty", (1,)),
    "orthogonal 0.5": ("orthogonal", 0.5, None, "exact", (1, 2)),
    "orthogonal 0.5 penalty": ("orthogonal", 0.5, None, "penalty", (1,)),
    "satin4 2x2 0.25": ("satin4", 0.25, (2, 2), "exact", (1,)),  # tests/test_hardening.py: the memory guard
    "satin4 4x4 0.25": ("satin4", 0.25, (4, 4), "exact", (1, 2)),
    "satin4 4x4 0.25 free edges": ("satin4", 0.25, (4, 4, "free"), "exact", (1, 2)),
    "satin4 8x8 0.25": ("satin4", 0.25, (8, 8), "exact", (2,)),
    # MUMPS' factors on disk (OUT_OF_CORE): the memory per dof the guard assumes with --out-of-core
    "satin4 2x2 0.25 out of core": ("satin4", 0.25, (2, 2), "exact out of core", (1,)),  # tests/test_hardening.py
    "satin4 4x4 0.25 out of core": ("satin4", 0.25, (4, 4), "exact out of core", (1, 2)),
    "satin4 8x8 0.25 out of core": ("satin4", 0.25, (8, 8), "exact out of core", (2,)),
}
QUICK = ("satin4 1.0", "satin4 0.5", "satin4 0.25", "satin4 0.125", "orthogonal 0.5")


def _rss_mb() -> float:
    """Resident set size of this process now [MB] (Linux /proc)."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def _peak_mb() -> float:
    """The peak resident set of this process's own memory since it started [MB]: VmHWM (Linux
    /proc), which exec resets. Not getrusage's ru_maxrss: a process started from a large one (a
    pytest session that has run many tests) reports its parent's size at the fork as its own peak
    (a 0.62 GB bench case read 0.86 GB from a long test session)."""
    try:
        with open("/proc/self/status") as f:
            return next(int(line.split()[1]) for line in f if line.startswith("VmHWM:")) / 1024
    except (OSError, StopIteration):
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def one_case(name: str) -> dict:
    """Run one case in this process (collective), stage by stage: the pipeline as `solve` runs it
    (its stages reported by pipeline.run's on_stage), then the metrics and the core outputs;
    rank 0 returns the record."""
    from mpi4py import MPI

    from textile_fenicsx.io.config import load_model
    from textile_fenicsx.model.coupon import tile
    from textile_fenicsx.model.weaves import build
    from textile_fenicsx.pipeline.stages import Settings, run
    from textile_fenicsx.plate.mesh.projected import MeshOptions
    from textile_fenicsx.plate.solver import SolverOptions

    comm = MPI.COMM_WORLD
    model, seed, repeats, method, _ = CASES[name]
    times, memory, peaks = {}, {}, {}
    current = [None, 0.0]  # the stage, when it began

    def sample():  # the largest resident set seen during each stage, every 20 ms
        while True:
            if current[0] is not None:
                peaks[current[0]] = max(peaks.get(current[0], 0.0), _rss_mb())
            time.sleep(0.02)

    threading.Thread(target=sample, daemon=True).start()
    settings = Settings(MeshOptions(seed), solver=SolverOptions(method=method.split()[0],
                                                                out_of_core=method.endswith("out of core")))

    def begin(label):
        """End the current stage (its time, the resident set summed over ranks) and begin `label`."""
        comm.barrier()
        if current[0] is not None:
            time.sleep(0.05)  # one more sample of this stage
            done = current[0]
            times[done] = time.perf_counter() - current[1]
            memory[done] = comm.allreduce(_rss_mb(), op=MPI.SUM)
            if comm.rank == 0:
                print(f"  {name}: {done} {times[done]:.2f} s, {memory[done]:.0f} MB", file=sys.stderr, flush=True)
        current[:] = [label, time.perf_counter()]

    begin("model")
    textile = load_model(SATIN) if model == "satin4" else build("orthogonal")
    textile = tile(textile, *repeats[:2], free_edges="free" in repeats) if repeats else textile
    result = run(textile, settings, comm, on_stage=begin)
    out = Path(os.environ.get("TEXTILE_FENICSX_BENCH_TMP", "/tmp")) / f"bench_{os.getpid() if comm.rank == 0 else 0}"
    out = Path(comm.bcast(str(out), root=0))
    begin("metrics")
    _ = result.metrics  # measured here, for the stage's time
    begin("export")
    result.write(out / "core", figures=False, fields=False, surfaces=False)
    if repeats is None:  # coupons: the surfaces of every yarn copy take minutes, skipped
        begin("extras")
        result.write(out / "full", figures=False)
    begin(None)
    times.setdefault("extras", float("nan"))
    if comm.rank == 0:
        import shutil

        shutil.rmtree(out, ignore_errors=True)
    ms, solution = result.midsurfaces, result.solution
    peak = _peak_mb()
    core = ("model", "mesh", "midsurfaces", "assemble", "solve", "correct", "metrics", "export")
    return {
        "case": name, "ranks": comm.size, "seed": seed, "repeats": repeats, "method": method,
        "dofs": int(sum(y.V.dofmap.index_map.size_global for y in ms.yarns)),
        "cells": int(ms.projected.stats["cells"]), "iterations": solution.iterations,
        "converged": bool(solution.converged), "verdict": bool(result.verdict["passed"]),
        "time_s": {**{k: times[k] for k in core}, "end_to_end": sum(times[k] for k in core),
                   "extras": times["extras"]},
        "memory_mb": {"peak_sum": comm.allreduce(peak, op=MPI.SUM), "peak_max_rank": comm.allreduce(peak, op=MPI.MAX),
                      "after_stage_sum": memory,
                      "stage_peak_max_rank": {k: comm.allreduce(peaks.get(k, 0.0), op=MPI.MAX) for k in memory},
                      "stage_peak_sum": {k: comm.allreduce(peaks.get(k, 0.0), op=MPI.SUM) for k in memory}},
    }


def cli_case(model: str, seed: float, runs: int = 3) -> dict:
    """The command a user runs, timed from outside in a fresh process: `textile-fenicsx solve MODEL
    --seed SEED --out DIR`, every output and figure included; the folder's size and its own
    account of where the time went (metrics.json time_s). Run `runs` times: the record is the
    median run's, with every run's wall time (one run on a shared machine is one sample of its
    load)."""
    import shutil
    import tempfile

    path = SATIN if model == "satin4" else model
    records = []
    for _ in range(runs):
        out = Path(tempfile.mkdtemp(prefix="bench-cli-")) / "run"
        start = time.perf_counter()
        proc = subprocess.run([sys.executable, "-m", "textile_fenicsx", "solve", str(path), "--seed", str(seed),
                               "--out", str(out)], capture_output=True, text=True, cwd=REPO)
        wall = time.perf_counter() - start
        record = {"case": f"{model} {seed} (CLI)", "seed": seed, "exit": proc.returncode, "wall_s": wall}
        if (out / "metrics.json").is_file():
            m = json.loads((out / "metrics.json").read_text())
            record.update(time_s=m["time_s"], dofs=m["dofs"], iterations=m["iterations"],
                          folder_mb=sum(f.stat().st_size for f in out.rglob("*") if f.is_file()) / 1e6,
                          outputs_fraction=m["time_s"]["outputs"] / wall)
        shutil.rmtree(out.parent, ignore_errors=True)
        records.append(record)
    median = sorted(records, key=lambda r: r["wall_s"])[len(records) // 2]
    return {**median, "runs_wall_s": [r["wall_s"] for r in records]}


def texgen_case(model: str, seed: float, timeout: float = 3600) -> dict:
    """TexGen's own solver on the same model (bench/texgen.py, pytexgen in its own venv: the
    python named by TEXTILE_FENICSX_TEXGEN_PYTHON, which `make bench` sets up); {} without it."""
    import tempfile

    python = os.environ.get("TEXTILE_FENICSX_TEXGEN_PYTHON", "")
    if not python or not os.access(python, os.X_OK):
        print("bench: TexGen's solver skipped: no pytexgen (make bench sets TEXTILE_FENICSX_TEXGEN_PYTHON through "
              "bench/texgen_env.sh --fenicsx-env)", file=sys.stderr, flush=True)
        return {}
    with tempfile.TemporaryDirectory(prefix="bench-texgen-") as tmp:
        proc = subprocess.run([python, str(REPO / "bench" / "texgen.py"), "solve", model, str(seed), tmp,
                               "--timeout", str(timeout)], capture_output=True, text=True, cwd=REPO)
    if proc.returncode != 0:
        print(f"bench: TexGen's solver failed: {proc.stderr.strip()[-300:]}", file=sys.stderr, flush=True)
        return {}
    try:
        return json.loads(proc.stdout[proc.stdout.index("\n{") + 1 if not proc.stdout.startswith("{") else 0:])
    except (ValueError, json.JSONDecodeError):  # bench/texgen.py prints its record last, indented
        print(f"bench: TexGen's solver printed no result: {proc.stdout.strip()[-300:]!r} "
              f"{proc.stderr.strip()[-300:]!r}", file=sys.stderr, flush=True)
        return {}


def _run(cmd: list[str]) -> str:
    proc = subprocess.run(cmd, stdout=subprocess.PIPE, text=True, cwd=REPO)
    if proc.returncode != 0:
        raise SystemExit(f"bench: {' '.join(cmd)} failed with exit code {proc.returncode}")
    return proc.stdout


def driver(names: list[str], out: Path) -> None:
    print("bench: warming the form cache", file=sys.stderr, flush=True)
    for warm in ("satin4", "orthogonal"):
        _run([sys.executable, "-c", "import textile_fenicsx as tfx; "
              f"[tfx.solve(tfx.build({'crowfoot_satin' if warm == 'satin4' else 'orthogonal'!r}), seed=1.0, "
              "method=m) for m in ('exact', 'penalty')]"])
    records = []
    for name in names:
        for ranks in CASES[name][4]:
            print(f"bench: {name} on {ranks} rank(s)", file=sys.stderr, flush=True)
            cmd = ([sys.executable] if ranks == 1 else ["mpirun", "-n", str(ranks), sys.executable])
            text = _run(cmd + [str(Path(__file__).resolve()), "--case", name])
            records.append(json.loads(text.strip().splitlines()[-1]))
    print("bench: the CLI as a user runs it, and TexGen's solver, on satin4.tg3 at seed 0.25", file=sys.stderr,
          flush=True)
    cli = cli_case("satin4", 0.25)
    texgen = texgen_case("satin4", 0.25)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"machine": os.uname().nodename, "cpus": os.cpu_count(), "load": os.getloadavg(),
                               "records": records, "cli": cli, "texgen": texgen}, indent=1))
    cols = ("model", "mesh", "midsurfaces", "assemble", "solve", "correct", "metrics", "export", "end_to_end", "extras")
    head = (f"{'case':26s} {'ranks':>5s} {'dofs':>8s} {'it':>4s} " + " ".join(f"{c[:8]:>8s}" for c in cols)
            + f" {'peak MB':>8s}")
    print(head)
    for r in records:
        print(f"{r['case']:26s} {r['ranks']:5d} {r['dofs']:8d} {r['iterations']:4d} "
              + " ".join(f"{r['time_s'][c]:8.2f}" for c in cols) + f" {r['memory_mb']['peak_sum']:8.0f}")
    print(f"(seconds; peak MB: resident set summed over ranks; written to {out})")
    if "wall_s" in cli:
        runs = ", ".join(f"{w:.1f}" for w in cli["runs_wall_s"])
        print(f"CLI `textile-fenicsx solve satin4.tg3 --seed 0.25 --out DIR` (figures included): {cli['wall_s']:.1f} s "
              f"wall (the median of {runs}), of which outputs "
              f"{cli.get('time_s', {}).get('outputs', float('nan')):.1f} s "
              f"({100 * cli.get('outputs_fraction', float('nan')):.0f} %), folder {cli.get('folder_mb', 0):.1f} MB")
    if texgen.get("seconds"):
        print(f"TexGen's solver, same model and seed: {texgen['seconds']:.0f} s: ours is "
              f"{texgen['seconds'] / cli['wall_s']:.0f} x faster")
    print(f"(load average during the bench: {', '.join(f'{v:.1f}' for v in os.getloadavg())})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--case", help="run one case here and print its record as JSON")
    parser.add_argument("--quick", action="store_true", help=f"only {', '.join(QUICK)}")
    parser.add_argument("--only", nargs="+", choices=list(CASES), metavar="NAME", help="these cases")
    parser.add_argument("--out", type=Path, default=REPO / "output" / "bench.json")
    args = parser.parse_args()
    if args.case:
        from mpi4py import MPI

        record = one_case(args.case)
        if MPI.COMM_WORLD.rank == 0:
            print(json.dumps(record), flush=True)
        return
    driver(args.only or (list(QUICK) if args.quick else list(CASES)), args.out)


if __name__ == "__main__":
    main()
