"""What `textile-fenicsx solve` prints: a summary line by default (the numbers are in metrics.json),
the JSON on request (--json); and the one-line reprs of the run objects a script holds."""

import json
import subprocess
import sys

import numpy as np
import pytest

from textile_fenicsx.api import solve
from textile_fenicsx.model.weaves import build


def textile_fenicsx(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "textile_fenicsx", *map(str, args)], capture_output=True, text=True,
                          timeout=300)


@pytest.mark.serial
def test_solve_prints_a_summary_and_the_json_only_when_asked(tmp_path):
    run = textile_fenicsx("solve", "plain", "--seed", 1.0, "--no-figures", "--out", tmp_path / "run")
    assert run.returncode == 0, run.stderr[-2000:]
    lines = run.stdout.splitlines()
    assert len(lines) == 2, run.stdout
    assert lines[0].startswith("plain: check passed; interpenetration ") and "Newton steps" in lines[0]
    assert str(tmp_path / "run") in lines[1]
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert f"{metrics['dofs']} dofs" in lines[0]

    run = textile_fenicsx("solve", "plain", "--seed", 1.0, "--json")  # no folder: the run's summary
    assert run.returncode == 0, run.stderr[-2000:]
    first, rest = run.stdout.split("\n", 1)
    assert first.startswith("plain: check passed")
    summary = json.loads(rest)
    assert summary["verdict"]["passed"] and summary["dofs"] == metrics["dofs"]


@pytest.mark.serial
def test_the_run_objects_print_on_one_line():
    run = solve(build("plain"), seed=1.0, remesh=0)  # the check is measured on first use
    for thing in (run, run.solution, run.midsurfaces, run.midsurfaces.yarns[0], run.midsurfaces.projected,
                  run.settings.plate):
        text = repr(thing)
        assert "\n" not in text and len(text) < 200, text
    assert repr(run).startswith("<Run 'plain': converged in ")
    assert repr(run).endswith("check not measured yet>")
    assert run.verdict["passed"] and repr(run).endswith("check passed>")
    # by default the run measures it, to know whether to mesh again (pipeline.run)
    assert repr(solve(build("plain"), seed=1.0)).endswith("check passed>")


@pytest.mark.serial
@pytest.mark.parametrize("ranks", [1, 2])
def test_solve_with_permeability_writes_the_cells_tensor_beside_its_volume_mesh(tmp_path, ranks):
    # `solve --volume-mesh voxel --permeability`, serially and on two ranks: the corrected plain
    # weave's voxel mesh (0.2 mm voxels, the default until issue 72: a small flow problem) and its
    # permeability in the same folder, K symmetric and positive definite,
    # in-plane Kxx = Kyy (the weave's quarter turn maps it onto itself), one summary line for each
    out = tmp_path / "run"
    launch = ["mpirun", "-n", "2"] if ranks > 1 else []
    r = subprocess.run([*launch, sys.executable, "-m", "textile_fenicsx", "solve", "plain", "--seed", "1.0",
                        "--no-figures", "--volume-mesh", "voxel", "--volume-size", "0.2", "--permeability",
                        "--fibre-radius", "0.0035", "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    doc = json.loads((out / "permeability.json").read_text())
    K = np.array(doc["K_m2"])
    assert np.abs(K - K.T).max() < 1e-6 * np.abs(K).max() and np.all(np.linalg.eigvalsh(0.5 * (K + K.T)) > 0)
    assert doc["checks"]["positive_definite"] and K[0, 0] == pytest.approx(K[1, 1], rel=1e-3)
    assert doc["vf"] == pytest.approx(json.loads((out / "mesh_report.json").read_text())["vf"], rel=1e-12)
    lines = r.stdout.splitlines()
    assert any(line.startswith("voxel mesh: ") for line in lines)
    assert any(line.startswith("Kxx ") and "m^2" in line for line in lines), r.stdout
    assert str(out / "permeability.json") in lines


@pytest.mark.serial
def test_solve_permeability_options_are_checked_before_any_work(tmp_path):
    # exit 2 and no output folder: --permeability without a volume mesh, its options without it,
    # a bad option of its own, and voxel layers asked of a tet mesh or none
    from textile_fenicsx.cli.volume_commands import PERMEABILITY_FILES
    from textile_fenicsx.flow.files import FILES

    assert set(PERMEABILITY_FILES) == {"permeability.json", *FILES}  # what Permeability.write writes
    out = tmp_path / "run"
    for args, words in ((["--permeability"], "--permeability needs --volume-mesh voxel|tet"),
                        (["--fibre-radius", "0.004"], "--fibre-radius needs --permeability"),
                        (["--yarn-permeability", "impermeable", "--volume-mesh", "voxel"],
                         "--yarn-permeability needs --permeability"),
                        (["--volume-mesh", "voxel", "--permeability", "--fibre-radius", "0"],
                         "fibre radius must be a positive length"),
                        (["--volume-mesh", "voxel", "--permeability", "--yarn-permeability", "leaky"],
                         "gebart, impermeable or a permeability"),
                        (["--volume-mesh", "tet", "--volume-layers", "3"], "layers through the thickness are a voxel"),
                        (["--volume-mesh", "voxel", "--volume-layers", "0"], "voxel layers must be a whole number")):
        r = textile_fenicsx("solve", "plain", *args, "--out", out)
        assert r.returncode == 2 and words in r.stderr, (args, r.stderr[-2000:])
        assert not out.exists()
