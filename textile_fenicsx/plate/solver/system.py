"""The Newton matrix and its checked solves (DESIGN.md 6): K's values put into its fixed pattern
(with the pinned unknown's row and column those of the identity; in (w, dt) where the yarns
flatten, basis.py), factorised by MUMPS' LDL^T without pivoting, and every solve checked:
converged, finite, no null pivot, and the inertia of a convex energy (no negative pivot beyond
round-off).
"""

import logging

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from textile_fenicsx.common.errors import UnresolvedError
from textile_fenicsx.plate.solver.basis import MidAndThickness
from textile_fenicsx.plate.solver.linear import DirectSolver, SolverError, mumps_error, negative_pivots, null_pivots
from textile_fenicsx.plate.solver.pattern import FixedPattern

__all__ = ["RESOLVED_WEIGHTS", "ROUND_OFF_PIVOTS", "NewtonSystem"]

log = logging.getLogger(__name__)

# negative pivots that round-off may give a nearly singular positive definite matrix
ROUND_OFF_PIVOTS = 2
# the factor resolves the plates' own stiffness while the interior point's weights (lam / s at the
# closed nodes) stay within this factor of the plates' largest diagonal entry: the relaxed solve caps
# them at 1e8 of a node's stiffness (solver/newton.py), so there the count of negative pivots is
# always read. Where the yarns flatten they grow to 1e12 (equilibrium needs it): the largest
# stiffness reaches 1e16-1e17 and every direction softer than its round-off (eps x 4e17 ~ 90 N/mm)
# has a pivot of either sign. The jammed plain weaves pressed to Vf 0.5 had 3 such pivots at an
# eigenvalue nearest zero of +4e-3 against 4e17 (1e-20 of it) and stopped as "not convex". Beyond this
# factor only the eigenvalue nearest zero is read: the energy's convexity (its plates, spring and
# compaction law; the weights add a positive semi-definite term) was read in the same solve's first
# factorisations, and in the relaxed solve on the same mesh before it
RESOLVED_WEIGHTS = 1e9


class NewtonSystem:
    """A ContactProblem's Newton matrix K (over `pattern`, or in (w, dt) through `basis`), its
    direct solver and the checks of its solves. pin: the unknown pinned in K, or None; Et: the
    apart spring [N/mm^3] (0: a yarn touching nothing is held by nothing); K_fixed: the constant
    part, whose largest diagonal entry is the plates' stiffness; template: a vector over the
    unknowns, duplicated for work vectors. `NewtonSystem` owns K and the solver and frees them in
    `destroy()`."""

    def __init__(self, comm: MPI.Comm, pattern: FixedPattern, basis: MidAndThickness | None, pin: int | None,
                 options: dict, Et: float, K_fixed: PETSc.Mat, template: PETSc.Vec):
        self.comm, self.pattern, self.basis, self.pin, self.Et = comm, pattern, basis, pin, Et
        self._template = template
        self.K = pattern.matrix() if basis is None else basis.matrix(pattern.values())
        self.solver = DirectSolver(comm, options)
        self.reset()
        diag = K_fixed.getDiagonal()
        self._plates_scale = diag.max()[1]  # the plates' (and spring's) largest stiffness [N/mm]
        diag.destroy()

    def reset(self) -> None:
        """No factorisation read yet (a problem renewed, ContactProblem.renew)."""
        self.factorisations, self._convex_checked, self._largest_weight = 0, -1, 0.0

    def factor(self, values: np.ndarray, c_nodes) -> PETSc.Mat:
        """K with the pattern's variable values `values` (in freeze's order), factorised; c_nodes:
        the interior point's weights at the nodes [N/mm], whose largest the checks read."""
        if self.basis is None:
            self.pattern.fill(self.K, values, pin=self.pin)
        else:  # a mould holds the translation: nothing is pinned
            self.basis.fill(self.K, self.pattern.values(values))
        self.K.setOption(PETSc.Mat.Option.SPD, True)  # pinned: MUMPS' SPD LDL^T (SYM = 1); new values reset it
        self._largest_weight = self.comm.allreduce(float(np.max(c_nodes, initial=0.0)), op=MPI.MAX)
        self.solver.factor(self.K)
        self.factorisations += 1
        return self.K

    def hold_pin(self, rhs: PETSc.Vec) -> None:
        """Set the pinned unknown's entry of a right-hand side to 0 (its row of the Newton matrix is
        the identity's: the solve then leaves it in place)."""
        if self.pin is not None:
            first, end = rhs.getOwnershipRange()
            if first <= self.pin < end:
                rhs.getArray()[self.pin - first] = 0.0

    def solve(self, rhs: PETSc.Vec, x: PETSc.Vec, what: str) -> None:
        """x = K^-1 rhs with K's last factorisation (`factor`), checked: converged, finite, no
        null pivots, and the inertia of a convex energy (no negative pivot). The pinned unknown
        does not move (its entry of rhs is set to 0). Where the yarns flatten, K is T^T K T in
        (w, dt) and x = T (T^T K T)^-1 T^T rhs (basis.py)."""
        self.hold_pin(rhs)
        if self.basis is None:
            self.solver.solve(rhs, x)
        else:
            r = rhs.duplicate()
            self.basis.transpose(rhs, r)
            self.solver.solve(r, x)
            x.copy(r)
            self.basis.apply(r, x)
            r.destroy()
        ksp = self.solver.ksp
        reason, nulls, negative = ksp.getConvergedReason(), null_pivots(ksp), negative_pivots(ksp)
        # a semi-definite matrix (Et = 0: a yarn touching nothing is held by nothing) factorised
        # without pivoting meets its null space as a pivot of round-off size and either sign
        held_by_nothing = self.Et == 0 and negative > 0
        if reason <= 0 or nulls > 0 or held_by_nothing:
            error, hint = SolverError, ("with Et = 0 a yarn that touches no other yarn is held by nothing: give "
                                        "Et > 0" if self.Et == 0 else
                                        "check the stiffnesses (Db1, Db2, sigma1) for zeros")
            if self._unresolved():
                error, hint = UnresolvedError, (f"the weights of the closed contacts ({self._largest_weight:.1e} "
                                                "N/mm) outgrew what the factor resolves of the plates: a mesh too "
                                                "coarse for the weave's corners; try a finer --seed")
            mumps = mumps_error(ksp)
            raise error(f"the linear system is singular at {what} (PETSc reason {reason}, {nulls} null pivots, "
                        f"{negative} negative{', ' + mumps if mumps else ''}): {hint}")
        if negative > 0 and self._convex_checked != self.factorisations:  # once per factorisation
            self._convex_checked = self.factorisations
            self._check_convex(negative, what)
        if not np.isfinite(x.norm()):
            raise SolverError(f"the solution is not finite (NaN or Inf) at {what}")

    def _check_convex(self, negative: int, what: str) -> None:
        """Negative pivots: a matrix that is not positive definite (an energy that is not convex:
        a bending penalty too weak for the mesh gave 96 on two crossing strips), or one so nearly
        singular that round-off flips a pivot's sign (a triangle of a yarn held by one vertex,
        rotating about it: an eigenvalue of 3e-14 of the largest stiffness, one negative pivot).
        More than ROUND_OFF_PIVOTS is an error; so is an eigenvalue nearest zero (inverse iteration
        with the factor, the Rayleigh quotient of the true matrix) below -1e-10 of the largest
        diagonal entry. Where the yarns flatten, the matrix is T^T K T (basis.py): congruent to K,
        with its signs, on a scale of its own. Where the interior point's weights exceed
        RESOLVED_WEIGHTS times the plates' stiffness, the count is round-off's and only the
        eigenvalue is read."""
        v, y, Kv = self._template.duplicate(), self._template.duplicate(), self._template.duplicate()
        first, end = v.getOwnershipRange()
        v.getArray()[:] = 1.0 + np.sin(np.arange(first, end))  # the same start on any partition
        for _ in range(4):
            v.scale(1.0 / v.norm())
            self.solver.solve(v, y)
            y.copy(v)
        v.scale(1.0 / v.norm())
        self.K.mult(v, Kv)
        eigenvalue, scale = v.dot(Kv), self.K.getDiagonal().max()[1]
        for vec in (v, y, Kv):
            vec.destroy()
        unresolved = self._unresolved()
        if (negative > ROUND_OFF_PIVOTS and not unresolved) or eigenvalue < -1e-10 * scale:
            error = UnresolvedError if unresolved else SolverError
            raise error(f"the energy is not convex at {what}: its matrix has {negative} negative pivots and an "
                        f"eigenvalue {eigenvalue:.2e} (largest stiffness {scale:.2e}; a mesh the bending penalty "
                        "cannot hold?)")
        log.warning("%s: the matrix is nearly singular (an eigenvalue %.1e, largest stiffness %.1e): %d pivot(s) "
                    "negative by round-off", what, eigenvalue, scale, negative)

    def _unresolved(self) -> bool:
        """Whether the last factorisation's weights outgrew what it resolves of the plates
        (RESOLVED_WEIGHTS)."""
        return self._largest_weight > RESOLVED_WEIGHTS * self._plates_scale

    def destroy(self) -> None:
        """Free the factors, then K."""
        self.solver.destroy()
        self.K.destroy()
