"""bench/outer_solve.py (make bench-outer) measures CG with one block per yarn on the contact steps'
matrices: its blocks must be the yarns' unknowns, and its CG must solve the step's system."""

import sys
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI
from petsc4py import PETSc

from textile_fenicsx.model.weaves import build
from textile_fenicsx.plate.mesh.midsurface import mid_surfaces
from textile_fenicsx.plate.mesh.projected import MeshOptions, projected_mesh
from textile_fenicsx.plate.solver import ContactProblem
from textile_fenicsx.plate.solver.newton import MAX_WEIGHT, _InteriorPoint

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
from outer_solve import BLOCKS, cg_solve, yarn_splits  # noqa: E402


@pytest.mark.mpi
def test_outer_solve_blocks_are_the_yarns_and_cg_solves_the_step():
    comm = MPI.COMM_WORLD
    ms = mid_surfaces(projected_mesh(build("plain"), MeshOptions(1.0), comm))
    problem = ContactProblem(ms)
    try:
        splits = yarn_splits(problem)
        # a partition of this rank's unknowns, one part per yarn: each yarn's own dofs map into its part
        owned = np.sort(np.concatenate([s.getIndices() for s in splits]))
        first = problem.numbering.start
        assert np.array_equal(owned, np.arange(first, first + problem.numbering.n_local))
        for y in ms.yarns:
            local = np.arange(y.V.dofmap.index_map.size_local)
            mine = problem.numbering.yarn_unknowns(y, local)
            mine = mine[(mine >= first) & (mine < first + problem.numbering.n_local)]
            assert np.isin(mine, splits[y.yarn].getIndices()).all()
        # the first interior-point step's matrix: CG with the yarn blocks gives the direct solve's answer
        ip = _InteriorPoint(problem)
        ip.step(1)
        problem.newton_matrix(c_nodes=np.minimum(ip.lam / ip.s, MAX_WEIGHT * ip.k))
        its, x = cg_solve(problem, {**BLOCKS, "ksp_rtol": 1e-13}, splits)
        direct = problem.b_fixed.duplicate()
        problem.solve(problem.b_fixed.copy(), direct, "direct")
        assert 0 < its < 3000
        scale = direct.norm(PETSc.NormType.INFINITY)
        direct.axpy(-1.0, x)
        assert direct.norm(PETSc.NormType.INFINITY) < 1e-8 * scale, (direct.norm(PETSc.NormType.INFINITY), scale)
        x.destroy()
        direct.destroy()
    finally:
        problem.destroy()
