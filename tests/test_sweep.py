"""The robustness sweep as a test (marked `sweep`: about an hour, so `make test` leaves it out;
run it with `bin/fenicsx-env python3 -m pytest -m sweep tests` or `make sweep` for the table):
the default command on every fabric of reference/fabrics and a few of our builders' must exit 0,
that is converge and pass the check of its corrected model (verify.py)."""

import sys

import pytest

from conftest import REPO

sys.path.insert(0, str(REPO / "bench"))
import sweep  # noqa: E402


@pytest.mark.sweep
@pytest.mark.slow
@pytest.mark.serial
@pytest.mark.parametrize("name", sweep.cases())
def test_default_command_on_the_fabric_family(name):
    record = sweep.run_case(name)
    assert record["exit"] == 0, record.get("failures") or record.get("error")
    assert record["passed"]
