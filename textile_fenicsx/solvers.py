"""PETSc solver options (plain dicts) and the checks every solve goes through."""

import numpy as np
from petsc4py import PETSc

# Sparse direct solves: iterative solvers do poorly on the 4th-order plate operator (DESIGN.md 6).
DIRECT_LU = {
    "ksp_type": "preonly",
    "pc_type": "lu",
    "pc_factor_mat_solver_type": "mumps",
}

# The contact problem's matrix is symmetric (plates, contact T^T M T, the pinning multiplier):
# MUMPS' symmetric-indefinite LDL^T stores half the factor and factorises ~15 % faster. ICNTL(24):
# detect null pivots, so a singular system (a yarn held by nothing) is reported, not solved quietly.
# ICNTL(7) = 2, AMF ordering: Debian's MUMPS has no METIS/SCOTCH and its automatic choice is PORD;
# on a 3.3e5-dof satin coupon AMF analysed + factorised + solved in 2.9 s vs PORD's 7.0 s serial
# (3.3 vs 5.0 s on 2 ranks) with 4 % fewer factor entries; on the unit cell (2e4 dofs) 0.1 vs 0.3 s.
DIRECT_LDLT = {
    "ksp_type": "preonly",
    "pc_type": "cholesky",
    "pc_factor_mat_solver_type": "mumps",
    "mat_mumps_icntl_7": 2,
    "mat_mumps_icntl_24": 1,
}


class SolverError(RuntimeError):
    """A linear or nonlinear solve did not converge, or gave a non-finite answer."""


def check_converged(ksp: PETSc.KSP, what: str) -> None:
    """Raise SolverError unless the KSP converged (collective: every rank sees the same reason)."""
    reason = ksp.getConvergedReason()
    if reason <= 0:
        raise SolverError(f"{what}: linear solve failed, KSP converged reason {reason}")
    norm = ksp.getSolution().norm()
    if not np.isfinite(norm):
        raise SolverError(f"{what}: the solution is not finite (norm {norm})")
