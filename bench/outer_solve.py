"""`make bench-outer`: can an iterative solve replace MUMPS in the contact steps (issue 18)?

The interior point (solver/newton.py) factorises K_fixed + C^T diag(w) C at every step, w = lam / s
the nodes' contact weights. A coupon of 10 million unknowns does not fit this machine that way, so
the issue asks whether an iterative outer solve over the yarns could take the direct solve's place.
This script follows the interior point on a model and, at some of its steps, solves the step's
matrix with conjugate gradients to a relative residual of 1e-10, preconditioned by
- "yarns": the yarns' diagonal blocks (each yarn's plate plus its nodes' weights) factorised
  exactly, additively (PCFIELDSPLIT, one split per yarn): what an outer solve over yarns is;
- "gamg": PETSc's algebraic multigrid, the usual preconditioner for a large elliptic matrix.
It prints the CG iterations per step (3000 = not converged) with the largest weight relative to
the plates' nodal stiffness; serial or under mpirun.

    python3 bench/outer_solve.py [--model reference/models/satin4.tg3] [--seed 0.25] [--steps 1 3 6 10 14]
"""

import argparse
from pathlib import Path

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from textile_fenicsx.io.tg3 import read_tg3
from textile_fenicsx.pipeline.stages import Settings
from textile_fenicsx.plate.mesh.midsurface import mid_surfaces
from textile_fenicsx.plate.mesh.projected import MeshOptions, projected_mesh
from textile_fenicsx.plate.solver import ContactProblem
from textile_fenicsx.plate.solver.linear import DirectSolver
from textile_fenicsx.plate.solver.newton import MAX_WEIGHT, _InteriorPoint

REPO = Path(__file__).resolve().parents[1]
CG = {"ksp_type": "cg", "ksp_rtol": 1e-10, "ksp_max_it": 3000}
BLOCKS = {"pc_type": "fieldsplit", "pc_fieldsplit_type": "additive",
          "fieldsplit_ksp_type": "preonly", "fieldsplit_pc_type": "cholesky"}
GAMG = {"pc_type": "gamg"}


def yarn_splits(problem: ContactProblem) -> list[PETSc.IS]:
    """Per yarn, the unknowns this rank owns (the numbering is yarn by yarn within each rank)."""
    first = problem.numbering.start
    end = first + problem.numbering.n_local
    splits = []
    for _, unknowns in problem.numbering.lookup:
        mine = np.sort(unknowns[(unknowns >= first) & (unknowns < end)]).astype(PETSc.IntType)
        splits.append(PETSc.IS().createGeneral(mine, comm=problem.comm))
    return splits


def cg_solve(problem: ContactProblem, options: dict, splits=None) -> tuple[int, PETSc.Vec]:
    """CG on the last Newton matrix for b_fixed (as the direct solve takes it): its iterations
    (3000 and more: not converged) and the solution (the caller destroys it). The KSP is
    linear.DirectSolver's, which owns any options dict under a prefix of its own."""
    solver = DirectSolver(problem.comm, {**CG, **options}, prefix="outer")
    if splits is not None:
        solver.ksp.getPC().setFieldSplitIS(*[(str(i), s) for i, s in enumerate(splits)])
    solver.factor(problem.K)  # sets up the preconditioner (the yarns' factors, or the multigrid)
    b, x = problem.b_fixed.copy(), problem.b_fixed.duplicate()
    problem.hold_pin(b)
    solver.solve(b, x)
    b.destroy()
    ksp = solver.ksp
    its = ksp.getIterationNumber() if ksp.getConvergedReason() > 0 else max(ksp.getIterationNumber(), 3000)
    solver.destroy()
    return its, x


def cg_iterations(problem: ContactProblem, options: dict, splits=None) -> int:
    its, x = cg_solve(problem, options, splits)
    x.destroy()
    return its


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default=str(REPO / "reference" / "models" / "satin4.tg3"))
    parser.add_argument("--seed", type=float, default=0.25)
    parser.add_argument("--steps", type=int, nargs="+", default=[1, 3, 6, 10, 14])
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    settings = Settings(MeshOptions(args.seed))
    ms = mid_surfaces(projected_mesh(read_tg3(args.model), settings.mesh, comm))
    problem = ContactProblem(ms, settings.plate, settings.solver)
    splits = yarn_splits(problem)
    ip = _InteriorPoint(problem)
    rows = []
    for it in range(1, max(args.steps) + 1):
        line = ip.step(it)  # factorises the step's matrix into problem.K
        if it in args.steps:
            w = np.minimum(ip.lam / ip.s, MAX_WEIGHT * ip.k)
            problem.newton_matrix(c_nodes=w)  # the next step's matrix, as the interior point builds it
            rows.append((it, line["mu"], ip.max(w / ip.k), cg_iterations(problem, BLOCKS, splits),
                         cg_iterations(problem, GAMG)))
    if comm.rank == 0:
        n = problem.K.getSize()[0]
        print(f"{Path(args.model).name}, seed {args.seed}: {n} unknowns, {len(splits)} yarns, {comm.size} rank(s); "
              "CG iterations to 1e-10 (3000: not converged)\n")
        print("| step | mu | largest w / k | yarn blocks | gamg |\n| --- | --- | --- | --- | --- |")
        for it, mu, w, blocks, gamg in rows:
            print(f"| {it} | {mu:.1e} | {w:.1e} | {blocks} | {gamg} |")
    problem.destroy()


if __name__ == "__main__":
    main()
