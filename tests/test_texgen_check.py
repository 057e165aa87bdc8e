"""Independent check against TexGen's own code (PyPI pytexgen), through bench/texgen.py.

Off unless asked for: TexGen runs in its own venv (bench/texgen_env.sh), never in this environment.

    bench/texgen_env.sh --fenicsx-env      # once, on the host: the venv inside the FEniCSx environment
    TEXTILE_FENICSX_TEXGEN=1 bin/fenicsx-env python3 -m pytest tests/test_texgen_check.py

With TEXTILE_FENICSX_TEXGEN=1 the tests ask bench/texgen_env.sh (run where the tests run) for the
venv's python, making the venv if it is not there yet. TEXTILE_FENICSX_TEXGEN_PYTHON=PATH names that
python instead; it must be runnable from the test process: inside bin/fenicsx-env's chroot only the
repository, /tmp and the chroot's own files are visible, and a venv made from the host's python does
not run there (`bench/texgen_env.sh --fenicsx-env` prints a path that does).
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
TEXGEN = REPO / "bench" / "texgen.py"
ENV_SCRIPT = REPO / "bench" / "texgen_env.sh"

pytestmark = [pytest.mark.serial, pytest.mark.slow]


def _tail(text, lines=15):
    return "\n".join(text.strip().splitlines()[-lines:])


@pytest.fixture(scope="module")
def texgen_python():
    path = os.environ.get("TEXTILE_FENICSX_TEXGEN_PYTHON")
    if path:
        if not (os.path.isfile(path) and os.access(path, os.X_OK)):
            pytest.skip(
                f"TEXTILE_FENICSX_TEXGEN_PYTHON={path} is not an executable file seen from this process "
                "(inside bin/fenicsx-env use the path that `bench/texgen_env.sh --fenicsx-env` prints)"
            )
        return path
    if os.environ.get("TEXTILE_FENICSX_TEXGEN") != "1":
        pytest.skip(
            "set TEXTILE_FENICSX_TEXGEN=1 to check against TexGen (installs pytexgen into a cached venv)"
        )
    run = subprocess.run(["bash", str(ENV_SCRIPT)], capture_output=True, text=True)
    if run.returncode != 0 or not run.stdout.strip():
        pytest.fail(
            "bench/texgen_env.sh could not provide pytexgen here (inside bin/fenicsx-env, run "
            f"`bench/texgen_env.sh --fenicsx-env` on the host first):\n{_tail(run.stderr)}"
        )
    return run.stdout.strip().splitlines()[-1]


def texgen_measure(python, tg3):
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    run = subprocess.run(
        [python, str(TEXGEN), "measure", str(tg3)], capture_output=True, text=True, env=env, timeout=900
    )
    if run.returncode != 0:
        pytest.fail(f"bench/texgen.py measure {tg3} failed (exit {run.returncode}):\n{_tail(run.stderr)}")
    return json.loads(run.stdout)


def _summary(after, before):
    ip = after["interpenetration"]
    change = [b / a - 1 for a, b in zip(before["yarn_volume"]["per_yarn"], after["yarn_volume"]["per_yarn"])]
    return (f"overlap volume {ip['volume']:.4g} mm^3 (before {before['interpenetration']['volume']:.4g}), "
            f"max depth {ip['max_depth']:.4g} mm, yarn volume changes "
            + ", ".join(f"{100 * c:+.2f} %" for c in change))


def test_texgen_measure_matches_reference(texgen_python, reference_dir):
    """Our TexGen measurement of the satin reproduces reference/texgen_measurements.json."""
    got = texgen_measure(texgen_python, reference_dir / "models" / "satin4.tg3")
    ref = json.loads((reference_dir / "texgen_measurements.json").read_text())["satin4"]["initial"]
    ip = got["interpenetration"]
    assert ip["volume"] == pytest.approx(ref["interpenetration"]["volume"], rel=0.03)
    assert ip["max_depth"] == pytest.approx(ref["interpenetration"]["max_z_overlap"], abs=0.005)
    assert got["yarn_volume"]["total"] == pytest.approx(ref["yarn_volume_sum_in_domain"], rel=0.01)
    assert got["thickness"] == pytest.approx(ref["thickness"], abs=0.005)


def test_corrected_plain_weave_in_texgen(texgen_python, reference_dir, tmp_path):
    """TexGen sees our corrected plain weave free of interpenetration, with the yarn volumes kept."""
    model = reference_dir / "models" / "plain.tg3"
    out = tmp_path / "out"
    run = subprocess.run(
        [sys.executable, "-m", "textile_fenicsx", "solve", str(model), "--seed", "0.5", "--no-figures",
         "--out", str(out)],
        cwd=REPO, capture_output=True, text=True, timeout=1800,
    )
    before = texgen_measure(texgen_python, model)
    if run.returncode != 0:
        message = f"textile_fenicsx solve failed (exit {run.returncode}):\n{_tail(run.stderr)}"
        if (out / "rejected.tg3").is_file():  # what TexGen makes of the model our check rejected
            seen = texgen_measure(texgen_python, out / "rejected.tg3")
            message += "\nTexGen on its rejected.tg3: " + _summary(seen, before)
        pytest.fail(message)
    after = texgen_measure(texgen_python, out / "corrected.tg3")

    v0, v1 = before["interpenetration"]["volume"], after["interpenetration"]["volume"]
    assert v0 > 0.1  # the model as saved interpenetrates (0.41 mm^3)
    assert v1 <= 0.01 * v0, f"overlap volume {v1:.4g} mm^3 after, {v0:.4g} before"
    assert after["interpenetration"]["max_depth"] <= 0.003  # 1 % of the 0.3 mm yarn height
    y0, y1 = before["yarn_volume"]["per_yarn"], after["yarn_volume"]["per_yarn"]
    assert len(y1) == len(y0)
    for i, (a, b) in enumerate(zip(y0, y1)):
        assert b == pytest.approx(a, rel=0.01), f"yarn {i}: volume {b:.5g} mm^3 after, {a:.5g} before"


def test_a_pressed_satin_in_texgen(texgen_python, tmp_path):
    """Issue 29: the 4-harness satin pressed to 0.6 of its relaxed thickness (0.868 mm at seed 0.5),
    its yarns flattened: TexGen, reading corrected.tg3, measures the thickness we measure and no
    overlap beyond the check's bounds."""
    out = tmp_path / "out"
    run = subprocess.run(
        [sys.executable, "-m", "textile_fenicsx", "solve", "crowfoot_satin", "--seed", "0.5", "--compaction", "50",
         "--mould", str(0.6 * 0.8681), "--no-figures", "--out", str(out)],
        cwd=REPO, capture_output=True, text=True, timeout=1800,
    )
    assert run.returncode == 0, _tail(run.stderr)
    ours = json.loads((out / "metrics.json").read_text())
    seen = texgen_measure(texgen_python, out / "corrected.tg3")
    assert seen["thickness"] == pytest.approx(ours["thickness"]["after"], abs=0.002)  # the rays' sampling
    assert seen["thickness"] < 0.6 * 0.8681 + 0.01  # the mould, and the sections between the plates' nodes
    assert seen["interpenetration"]["max_depth"] <= 0.003  # the check's: 1 % of the 0.3 mm yarns
    before = ours["interpenetration"]["before"]["volume"]
    assert seen["interpenetration"]["volume"] <= 0.01 * before


def test_a_stack_of_plies_is_texgens_layered_textile(texgen_python, tmp_path):
    """Issue 29: a stack of plies is written as TexGen's CTextileLayered (`build --plies`, and the
    corrected stack of `solve --plies`): TexGen reads each as a layered textile with its plies, and
    measures the corrected stack free of overlap, as thick as we measure it."""
    out = tmp_path / "out"
    built = subprocess.run(
        [sys.executable, "-m", "textile_fenicsx", "build", "plain", "--plies", "2", "--ply-offsets", "0,0", "1,1",
         "--no-picture", "--out", str(tmp_path / "built")], cwd=REPO, capture_output=True, text=True, timeout=600)
    assert built.returncode == 0, _tail(built.stderr)
    seen = texgen_measure(texgen_python, tmp_path / "built" / "plain.tg3")
    assert (seen["type"], seen["layers"], seen["n_yarns"]) == ("CTextileLayered", 2, 8)
    run = subprocess.run(
        [sys.executable, "-m", "textile_fenicsx", "solve", str(tmp_path / "built" / "plain.tg3"), "--seed", "0.5",
         "--no-figures", "--out", str(out)], cwd=REPO, capture_output=True, text=True, timeout=1800)
    assert run.returncode == 0, _tail(run.stderr)
    ours = json.loads((out / "metrics.json").read_text())
    assert ours["plies"] == 2
    seen = texgen_measure(texgen_python, out / "corrected.tg3")
    assert (seen["type"], seen["layers"]) == ("CTextileLayered", 2)
    assert seen["thickness"] == pytest.approx(ours["thickness"]["after"], abs=0.002)  # the rays' sampling
    assert seen["interpenetration"]["max_depth"] <= 0.003  # the check's: 1 % of the 0.3 mm yarns
