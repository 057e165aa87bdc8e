"""What `textile-fenicsx solve` prints: a summary line by default (the numbers are in metrics.json),
the JSON on request (--json); and the one-line reprs of the run objects a script holds."""

import json
import subprocess
import sys

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
