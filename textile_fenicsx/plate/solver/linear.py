"""Sparse direct solves: PETSc options as plain dicts, one object that owns the KSP, and the checks
every factorisation goes through (convergence, null pivots, inertia)."""

import itertools

import numpy as np
from petsc4py import PETSc

from textile_fenicsx.common.errors import SolverError
from textile_fenicsx.common.petsc import petsc_options

__all__ = ["DIRECT_LDLT", "DIRECT_LU", "OUT_OF_CORE", "DirectSolver", "SolverError", "check_converged"]

# Sparse direct solves: iterative solvers do poorly on the 4th-order plate operator (DESIGN.md 6).
DIRECT_LU = {
    "ksp_type": "preonly",
    "pc_type": "lu",
    "pc_factor_mat_solver_type": "mumps",
}

# The contact problem's matrix is symmetric (plates, contact) and, with one unknown pinned,
# positive definite: the problem flags it SPD and MUMPS factorises it as LDL^T without pivoting
# (SYM = 1), which keeps the analysis' prediction of the factor exact however the interior point's
# weights scale the pivots, stores half the factor, and is ~15 % faster than LU. Other symmetric
# matrices get the symmetric-indefinite LDL^T (SYM = 2). ICNTL(24): detect null pivots, so a
# singular system (a yarn held by nothing) is reported, not solved quietly. ICNTL(13) = 1: no
# ScaLAPACK on the root front, so that INFOG(12), the number of negative pivots (the inertia), is
# exact on any number of ranks: a convex energy's matrix has none (MUMPS counts them with SYM = 1
# too). ICNTL(7) = 4, PORD ordering (Debian's MUMPS has no METIS/SCOTCH). Measured 2026-11-24 on
# satin4, whole solves (23-31 factorisations, one analysis since the second solve renews the
# problem): seed 0.125 serial PORD 17.7 s, AMF 19.5, AMD 18.3, QAMD 18.0; on 2 ranks PORD 11.4, AMF
# 11.8; seed 0.25 PORD 2.3, AMF 2.4; the 4 x 4 coupon (3.3e5 dofs) PORD 67.9 s, AMF 68.4. (AMF had
# been chosen from an earlier measurement on that coupon, one analysis + factorisation + solve: 2.9 s
# with AMF, 7.0 s with PORD; whole solves no longer show it.)
# ICNTL(14) = 50: the factorisation's workspace is the analysis' estimate + 50 % (MUMPS' default
# 20 %). On 2 ranks, MUMPS places parts of the fronts on the less loaded process while it
# factorises, so a rank can need more than estimated: with four MPI processes sharing the 2 cores,
# the 2-rank tests' satin failed with INFOG(1) = -9 (54 153 entries short) at 20 %. Pages of the
# margin that are not used are never touched: a 2x2 satin coupon peaked at 647 MB, 642 at 20 %.
# MUMPS' fill-reducing ordering (ICNTL(7)) and the two the solves use
ORDERING, PORD, AMF = "mat_mumps_icntl_7", 4, 2
DIRECT_LDLT = {
    "ksp_type": "preonly",
    "pc_type": "cholesky",
    "pc_factor_mat_solver_type": "mumps",
    ORDERING: PORD,
    "mat_mumps_icntl_13": 1,
    "mat_mumps_icntl_14": 50,
    "mat_mumps_icntl_24": 1,
}

# Where the yarns flatten, the Newton systems are solved in (w, dt) with the apart spring lumped
# (basis.py, forms/contact.py): the dt unknowns couple to their own node's w and to the yarns in
# contact there only. PORD orders that pattern badly and AMF well. Satin4 to Vf 0.55, a
# factorisation (mean of 26-27) at seed 0.5: PORD 0.058 s (2.10 M entries in the factor, 7.0e8
# flops), AMF 0.038 (1.70 M, 3.4e8); at seed 0.25: PORD 0.301 s (7.57 M, 6.2e9), AMF 0.100 (4.39 M,
# 1.2e9), AMD and QAMD 0.106-0.112 (4.81 M). With the consistent spring, PORD had taken 0.063 and
# 0.184 s. The relaxed problem keeps PORD (AMF 0.037 s against 0.032 at seed 0.5).
def flattening_options(options: dict) -> dict:
    """The linear options of a problem whose yarns flatten: AMF where they order by PORD (DIRECT_LDLT's
    choice; an ordering of the user's own is kept)."""
    return {**options, ORDERING: AMF} if options.get(ORDERING) == PORD else dict(options)


# Added to DIRECT_LDLT for large coupons: MUMPS writes its factors to disk (ICNTL(22) = 1, in
# $MUMPS_OOC_TMPDIR, else /tmp) and keeps only the fronts it works on in memory. On a 3.3e5-dof
# satin coupon the solve stage needed 2.3 x less memory and took 15-25 % longer (README, Performance).
OUT_OF_CORE = {"mat_mumps_icntl_22": 1}

_serial = itertools.count()


def check_converged(ksp: PETSc.KSP, what: str) -> None:
    """Raise SolverError unless the KSP converged to a finite answer without null pivots
    (collective: every rank sees the same reason)."""
    reason = ksp.getConvergedReason()
    nulls = null_pivots(ksp)
    if reason <= 0 or nulls > 0:
        raise SolverError(f"{what}: the linear system is singular or the solve failed (PETSc reason {reason}, "
                          f"{nulls} null pivots)")
    norm = ksp.getSolution().norm()
    if not np.isfinite(norm):
        raise SolverError(f"{what}: the solution is not finite (norm {norm})")


def null_pivots(ksp: PETSc.KSP) -> int:
    """Null pivots MUMPS found (ICNTL(24) = 1); 0 for other solvers."""
    return _mumps_infog(ksp, 28)


def mumps_error(ksp: PETSc.KSP) -> str:
    """MUMPS' own status after a failed factorisation (INFOG(1), INFOG(2)), or ''."""
    code, detail = _mumps_infog(ksp, 1), _mumps_infog(ksp, 2)
    return f"MUMPS INFOG(1) = {code}, INFOG(2) = {detail}" if code < 0 else ""


def negative_pivots(ksp: PETSc.KSP) -> int:
    """Negative pivots of MUMPS' LDL^T factor (INFOG(12), the matrix's number of negative
    eigenvalues); -1 for other solvers."""
    return _mumps_infog(ksp, 12, missing=-1)


def _mumps_infog(ksp: PETSc.KSP, k: int, missing: int = 0) -> int:
    try:
        return int(ksp.getPC().getFactorMatrix().getMumpsInfog(k))
    except (PETSc.Error, AttributeError):
        return missing


class DirectSolver:
    """A KSP for repeated solves with one matrix pattern. The options dict is written under a
    prefix of its own and removed from PETSc's global database once read: the KSP reads its part
    in the constructor, the factor (MUMPS' ICNTL) its part at the first factorisation, so the
    keys go after the first solve. `destroy()` frees the KSP and its factors."""

    def __init__(self, comm, options: dict, prefix: str = "tfx_contact"):
        self.ksp = PETSc.KSP().create(comm)
        self._prefix = f"{prefix}_{next(_serial)}_"
        self.ksp.setOptionsPrefix(self._prefix)
        self._options = petsc_options(self._prefix, options)  # closed after the first factorisation
        try:
            self.ksp.setFromOptions()
        except Exception:
            self._options.close()
            raise

    def factor(self, A: PETSc.Mat) -> None:
        """Factorise A (numerically only after the first time: the pattern stays)."""
        self.ksp.setOperators(A)
        try:
            self.ksp.setUp()
        finally:
            self._options.close()

    def solve(self, b: PETSc.Vec, x: PETSc.Vec) -> None:
        """x = A^-1 b with the last factorisation."""
        self.ksp.solve(b, x)

    def destroy(self) -> None:
        self._options.close()
        self.ksp.destroy()
