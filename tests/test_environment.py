"""The environment is the one the project is built for (DESIGN.md section 10)."""

import os
import subprocess
import sys

import pytest
from mpi4py import MPI

from conftest import REPO


@pytest.mark.serial
def test_dolfinx_is_0_9():
    import basix
    import ufl

    import dolfinx

    assert dolfinx.__version__.startswith("0.9."), dolfinx.__version__
    assert basix.__version__.startswith("0.9."), basix.__version__
    assert ufl.__version__.startswith("2024.2"), ufl.__version__


@pytest.mark.serial
def test_stack_imports_and_solvers():
    import dolfinx_mpc  # noqa: F401
    import gmsh
    import meshio  # noqa: F401
    from petsc4py import PETSc

    assert gmsh.__version__.split(".")[0] == "4"
    # MUMPS is the direct solver of the design; check the PETSc build really has it.
    A = PETSc.Mat().createAIJ([2, 2], comm=PETSc.COMM_SELF)
    A.setValues([0, 1], [0, 1], [[2.0, 0.0], [0.0, 4.0]])
    A.assemble()
    ksp = PETSc.KSP().create(PETSc.COMM_SELF)
    ksp.setOperators(A)
    ksp.setType("preonly")
    ksp.getPC().setType("lu")
    ksp.getPC().setFactorSolverType("mumps")
    b, x = A.createVecs()
    b.set(1.0)
    ksp.solve(b, x)
    assert x.getArray() == pytest.approx([0.5, 0.25])


@pytest.mark.serial
def test_single_threaded_openblas_selected():
    assert os.environ.get("OPENBLAS_NUM_THREADS") == "1"
    assert os.environ.get("OMP_NUM_THREADS") == "1"
    import numpy as np

    np.dot(np.ones((64, 64)), np.ones((64, 64)))
    # numpy links libblas.so.3; Debian's alternatives must point it at OpenBLAS, not reference BLAS.
    libs = [line.split()[-1] for line in open("/proc/self/maps") if "blas" in line.lower()]
    assert any("openblas" in lib for lib in libs), libs


@pytest.mark.serial
def test_package_layout_imports():
    import textile_fenicsx
    import textile_fenicsx.plate.forms
    import textile_fenicsx.plate.mesh

    assert textile_fenicsx.plate.forms.__name__ == "textile_fenicsx.plate.forms"
    assert textile_fenicsx.plate.mesh.__name__ == "textile_fenicsx.plate.mesh"
    out = subprocess.run(["textile-fenicsx", "--version"], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == f"textile-fenicsx {textile_fenicsx.__version__}"


@pytest.mark.mpi
def test_mpi_world_matches_launcher():
    comm = MPI.COMM_WORLD
    expected = int(os.environ.get("OMPI_COMM_WORLD_SIZE", "1"))
    assert comm.size == expected
    assert comm.allreduce(comm.rank, op=MPI.SUM) == comm.size * (comm.size - 1) // 2
    assert sys.executable


@pytest.mark.serial
def test_installed_package_holds_every_module(tmp_path):
    # pip installs the package as pyproject.toml lists it; every module of the source tree must
    # then import from the installation (was: textile_fenicsx.plate.solver missing, so the Docker image,
    # which runs the installed package, failed at its first solve)
    import shutil

    source, target = tmp_path / "source", tmp_path / "site"  # a copy: no stale build/ of the clone's
    shutil.copytree(REPO, source, ignore=shutil.ignore_patterns(".git", "build", "*.egg-info", "output",
                                                                "__pycache__", "reference"))
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation",
                    "--break-system-packages", "--target", str(target), str(source)], check=True,
                   capture_output=True, cwd=tmp_path)
    env = dict(os.environ, PYTHONPATH=str(target))
    run = subprocess.run([sys.executable, str(REPO / "bin" / "check-install"), str(REPO)], env=env,
                         capture_output=True, text=True, cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    assert "modules import from the installation" in run.stdout
    assert (target / "textile_fenicsx" / "py.typed").is_file()  # PEP 561: the annotations are shipped
