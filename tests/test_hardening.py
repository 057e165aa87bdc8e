"""Issue 8: every bad input and failure mode gets a clear answer, nothing half-written is left, and
MPI never hangs. Each case feeds the bad thing and asserts the message and the clean state; the
README table "When things go wrong" lists them. (Reader fuzzing and the input-value table are in
test_io.py.)"""

import json
import os
import select
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from mpi4py import MPI

from conftest import REPO
from textile_fenicsx.cli import build_parser
from textile_fenicsx.config import load_model
from textile_fenicsx.coupon import tile
from textile_fenicsx.errors import GeometryError, TextileError
from textile_fenicsx.meshes.midsurface import mid_surfaces
from textile_fenicsx.meshes.projected import MeshOptions, estimated_dofs, projected_mesh
from textile_fenicsx.sections import Ellipse
from textile_fenicsx.solver import PlateParameters, SolverOptions, solve
from textile_fenicsx.errors import SolverError
from textile_fenicsx.textile import Cell, Textile
from textile_fenicsx.weaves import build
from textile_fenicsx.yarn import ConstantSection, Yarn

CLI = ["textile-fenicsx"]


def cli(*args, timeout=300, mpi=0):
    cmd = (["mpirun", "-n", str(mpi)] if mpi else []) + CLI + [str(a) for a in args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)


def leftovers(folder):
    """Everything in `folder` (a clean state is an empty listing)."""
    return sorted(p.name for p in folder.iterdir())


def strip(L=4.0, z=0.0, name="s", along_x=True, width=1.0):
    reps = [[L, 0, 0], [0, L, 0]]
    nodes = [[0, L / 2, z], [L / 2, L / 2, z], [L, L / 2, z]] if along_x else \
        [[L / 2, 0, z], [L / 2, L / 2, z], [L / 2, L, z]]
    return Yarn(nodes, ConstantSection(Ellipse(width, 0.2)), "linear", repeats=reps, name=name)


# --- 1. inputs ----------------------------------------------------------------------------------

@pytest.mark.serial
def test_non_periodic_yarn_path_is_named():
    # the last node is not the first moved by whole cells: the pattern cannot repeat
    y = Yarn([[0, 2, 0], [2, 2, 0.1], [3.5, 2, 0]], ConstantSection(Ellipse(1, 0.2)), name="warp 3")
    with pytest.raises(TextileError, match=r"warp 3: not periodic over the cell.*\(3.5, 0, 0\)"):
        Textile(Cell(4, 4), [y])


@pytest.mark.serial
@pytest.mark.parametrize("params, message", [
    (dict(Ec=float("nan")), "Ec must be finite"),
    (dict(sigma1=float("inf")), "sigma1 must be finite"),
    (dict(Db2=-1.0), "Db2 must be >= 0"),
    (dict(Et="soft"), "Et must be a number"),
])
def test_bad_moduli_are_named(params, message):
    with pytest.raises(TextileError, match=message):
        PlateParameters(**params)


@pytest.mark.serial
@pytest.mark.parametrize("options, message", [
    (dict(seed=float("nan")), "seed must be a positive size"),
    (dict(seed=0.5, memory_limit=-2), "memory limit must be a positive size"),
])
def test_bad_mesh_options_are_named(options, message):
    with pytest.raises(TextileError, match=message):
        MeshOptions(**options)


@pytest.mark.serial
def test_seed_beyond_the_memory_limit_is_refused_before_meshing(reference_dir, tmp_path):
    # the estimate: 4.6 x footprint area / seed^2 unknowns (checked here against a real mesh at a
    # fine seed, where it matters; coarse seeds get more cells from the gaps between yarns) at
    # 12.5 kB each; a seed of 0.005 mm on the satin would need ~0.3e9 unknowns: refused at once
    t = load_model(reference_dir / "models" / "satin4.tg3")
    real = sum(y.V.dofmap.index_map.size_global
               for y in mid_surfaces(projected_mesh(t, MeshOptions(0.125), MPI.COMM_SELF)).yarns)
    assert 0.8 * real < estimated_dofs(t, 0.125) < 1.2 * real
    start = time.perf_counter()
    run = cli("solve", reference_dir / "models" / "satin4.tg3", "--seed", 0.005, "--out", tmp_path / "run")
    assert run.returncode == 2
    assert "mesh seed 0.005 mm would give about" in run.stderr and "GB" in run.stderr
    assert "use a larger seed" in run.stderr
    assert time.perf_counter() - start < 60  # no meshing happened (that would take hours)
    assert leftovers(tmp_path) == []
    run = cli("mesh", reference_dir / "models" / "satin4.tg3", "--seed", 0.25, "--memory-limit", 0.01)
    assert run.returncode == 2 and "the memory limit you gave (0.0 GB)" in run.stderr


@pytest.mark.serial
@pytest.mark.parametrize("args, message", [
    (["plain", "--repeat", "0", "2"], "coupon repeats nx must be a whole number >= 1"),
    (["plain", "--free-edges"], "--free-edges needs --repeat"),
    (["plain", "--seed", "-1"], "seed must be a positive size"),
    (["plain", "--seed", "9"], "larger than the cell"),
    (["nosuchweave.toml"], "nosuchweave.toml"),
    (["plain", "--ec", "0"], "Ec must be > 0"),
])
def test_cli_bad_input_exits_2_naming_it(args, message, tmp_path):
    run = cli("solve", *args, "--out", tmp_path / "run")
    assert run.returncode == 2, run.stderr
    assert message in run.stderr
    assert "Traceback" not in run.stderr
    assert leftovers(tmp_path) == []


# --- 2. geometry the method cannot handle -------------------------------------------------------

@pytest.mark.mpi
def test_yarns_on_top_of_each_other_have_no_stacking_order():
    # two identical strips at the same height: which is on top is undecided; named with a place
    t = Textile(Cell(4, 4), [strip(name="upper strip"), strip(name="twin"), strip(z=0.4, along_x=False, name="cross")])
    with pytest.raises(GeometryError, match=r"upper strip \(yarn 0\) and twin \(yarn 1\) lie at the same height"
                                            r".*around \("):
        mid_surfaces(projected_mesh(t, MeshOptions(0.5)))


@pytest.mark.mpi
def test_empty_footprint_is_named():
    # a non-periodic yarn entirely outside the cell has no footprint on the mesh
    outside = Yarn([[10, 1, 0], [12, 1, 0]], ConstantSection(Ellipse(1, 0.2)), periodic=False, name="stray")
    t = Textile(Cell(4, 4), [strip(), outside])
    with pytest.raises(GeometryError, match=r"stray \(yarn 1\) has an empty footprint"):
        mid_surfaces(projected_mesh(t, MeshOptions(0.5)))


# --- 3. solver --------------------------------------------------------------------------------

@pytest.mark.serial
def test_cap_reached_exits_1_and_marks_the_folder_failed(tmp_path):
    out = tmp_path / "run"
    run = cli("solve", "plain", "--seed", 1.0, "--max-iterations", 2, "--out", out)
    assert run.returncode == 1
    assert "reached its cap of 2 steps" in run.stderr and "FAILED and log.json" in run.stderr
    assert leftovers(out) == ["FAILED", "log.json"]
    log = json.loads((out / "log.json").read_text())
    assert len(log["history"]) == 2 and log["history"][-1]["moved_mm"] > SolverOptions().displacement_tol
    assert "cap of 2 steps" in (out / "FAILED").read_text()
    # a later good run into the same folder replaces the failure marks
    assert cli("solve", "plain", "--seed", 1.0, "--no-figures", "--out", out).returncode == 0
    assert "FAILED" not in leftovers(out) and "metrics.json" in leftovers(out)
    assert [p.name for p in tmp_path.iterdir()] == ["run"]


@pytest.mark.mpi
def test_singular_system_says_why():
    # two strips that never touch (0.6 mm apart) and Et = 0: nothing holds either one up
    t = Textile(Cell(4, 4), [strip(z=0.0, name="low"), strip(z=0.8, along_x=False, name="high")])
    ms = mid_surfaces(projected_mesh(t, MeshOptions(0.5)))
    with pytest.raises(SolverError, match=r"singular.*Et = 0.*give Et > 0"):
        solve(ms, PlateParameters(Et=0.0), SolverOptions(method="penalty"))
    # the exact method needs Et > 0 for every model (contact holds a yarn from one side only)
    with pytest.raises(TextileError, match=r"Et must be > 0 with the exact contact"):
        solve(ms, PlateParameters(Et=0.0), SolverOptions())


@pytest.mark.mpi
def test_non_finite_solution_is_caught():
    t = Textile(Cell(4, 4), [strip(z=0.0, name="low"), strip(z=0.2, along_x=False, name="high")])
    ms = mid_surfaces(projected_mesh(t, MeshOptions(0.5)))
    with pytest.raises(SolverError, match=r"not finite|singular"):
        solve(ms, PlateParameters(), SolverOptions(), loads={0: float("inf")})


# --- 4. MPI -------------------------------------------------------------------------------------

@pytest.mark.serial
def test_error_on_one_rank_ends_every_rank(tmp_path):
    # only rank 0 writes the output folder: an unwritable place fails there alone while rank 1
    # waits in a collective call; the run must end (not hang) with the message and exit code 1
    start = time.perf_counter()
    run = cli("solve", "plain", "--seed", 1.0, "--no-figures", "--out", "/proc/textile-fenicsx-test/run",
              mpi=2, timeout=240)
    assert run.returncode != 0
    assert "textile-fenicsx: error: cannot read or write" in run.stderr
    assert time.perf_counter() - start < 200


@pytest.mark.serial
@pytest.mark.parametrize("args", [("crowfoot_satin", "--seed", 1.0)])
def test_serial_and_two_rank_outputs_are_the_same(args, tmp_path):
    runs = {}
    for ranks in (0, 2):
        out = tmp_path / f"run{ranks}"
        run = cli("solve", *args, "--no-figures", "--out", out, mpi=ranks)
        assert run.returncode == 0, run.stderr[-2000:]
        runs[ranks] = out
    assert leftovers(runs[0]) == leftovers(runs[2])
    a, b = (json.loads((runs[k] / "metrics.json").read_text()) for k in (0, 2))
    a.pop("time_s"), b.pop("time_s")
    assert (a.pop("ranks"), b.pop("ranks")) == (1, 2)
    # the reason quotes the last step's size, a number at round-off level on either partition
    assert a.pop("reason").startswith("converged") and b.pop("reason").startswith("converged")

    def compare(x, y, where):
        if isinstance(x, dict):
            assert x.keys() == y.keys(), where
            for k in x:
                compare(x[k], y[k], f"{where}.{k}")
        elif isinstance(x, list):
            assert len(x) == len(y), where
            for k, (u, v) in enumerate(zip(x, y)):
                compare(u, v, f"{where}[{k}]")
        elif isinstance(x, float):
            assert y == pytest.approx(x, rel=1e-8, abs=1e-8), where
        else:
            assert x == y, where

    compare(a, b, "metrics")
    ca, cb = (load_model(runs[k] / "corrected.json") for k in (0, 2))
    for ya, yb in zip(ca.yarns, cb.yarns):
        assert np.allclose(ya.nodes, yb.nodes, rtol=0, atol=1e-8)
        for sa, sb in zip(ya.section.sections(), yb.section.sections()):
            assert np.allclose(sa.vertices, sb.vertices, rtol=0, atol=1e-8)


# --- 5. interrupts ------------------------------------------------------------------------------

@pytest.mark.serial
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_interrupt_during_the_solve_leaves_nothing(sig, tmp_path):
    out = tmp_path / "run"
    proc = subprocess.Popen(CLI + ["solve", "orthogonal", "--seed", "0.5", "--out", str(out)],
                            stderr=subprocess.PIPE, text=True)
    seen, deadline = "", time.time() + 120
    while "contact step   2" not in seen and time.time() < deadline:
        ready, _, _ = select.select([proc.stderr], [], [], 1.0)
        if ready:
            seen += proc.stderr.readline()
    assert "contact step   2" in seen, seen
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130
    assert "interrupted" in err and "no output was written" in err
    assert leftovers(tmp_path) == []


# --- 6. the command line documents itself -------------------------------------------------------

@pytest.mark.serial
def test_every_option_of_every_command_has_help():
    import argparse

    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert set(commands.choices) == {"versions", "report", "build", "mesh", "solve"}
    for name, sub in commands.choices.items():
        assert sub.description or name == "versions", name
        text = sub.format_help()
        for action in sub._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            assert action.help and action.help != argparse.SUPPRESS, f"{name} {action.dest}"
            for flag in action.option_strings:
                assert flag in text, f"{name} {flag}"
    assert "Exit codes" in parser.format_help() and "130 interrupted" in parser.format_help()


@pytest.mark.mpi
def test_hard_penalty_converges_with_damped_steps():
    # two crossing strips pressed together with a penalty of 1e8 N/mm^3 (1e5 x the paper's): the
    # undamped active set flipped between two states at the contact edge and had to stop. The
    # damped steps (halved until the energy falls) converge; the answer is symmetric and the
    # contact force, Ec x penetration volume, balances the load on the upper strip
    from test_solver import crossing_strips, integral

    ms = mid_surfaces(projected_mesh(crossing_strips(), MeshOptions(0.25)))
    sol = solve(ms, PlateParameters(Ec=1e8), SolverOptions(method="penalty"), loads={0: -0.05, 1: 0.05})
    assert sol.converged, sol.reason
    assert min(h["step"] for h in sol.history) < 1  # damping was needed
    up, low = (integral(w, y.dx) for w, y in zip(sol.w, ms.yarns))
    assert up == pytest.approx(-low, rel=1e-6) and up < 0
    load = 0.05 * integral(1.0 + 0 * sol.w[0], ms.yarns[0].dx)
    assert sol.penetration_volume * 1e8 == pytest.approx(load, rel=1e-3)
