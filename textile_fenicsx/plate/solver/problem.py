"""The assembled problem: plates, the pinned translation and the contact pairs over the unknowns.

Energy (DESIGN.md 5), with x the unknowns:
    E(x) = 1/2 x^T K0 x - b0^T x + sum_pairs E_c(g_p),   g_p = g0_p + T_p x,
K0 the plates (each yarn's bending + tension on its submesh, reduced by the periodic map R_i:
K0 = sum R_i^T A_i R_i), b0 their restoring force -A_i z0_i (and any load), E_c the
contact energy of forms/contact.py. For the exact method E_c is quadratic (the apart spring) and
joins the fixed part: K_fixed = K0 + sum T^T J T, b_fixed = b0 - sum T^T J g0.
E does not change when every yarn rises by the same amount (without a foundation or a mould): the
Newton matrices pin one unknown instead, so that they are symmetric positive definite (MUMPS'
Cholesky without pivoting, whatever the interior point's weights), and the solution is shifted
to zero mean afterwards. A mould holds that translation itself: every node has its platens'
weights in the interior point's matrix, and nothing is pinned.
`ContactProblem` owns the PETSc objects it makes (K, K_fixed, vectors, the direct solver) and
frees them in `destroy()`.
"""

import logging
from dataclasses import replace

import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

import dolfinx
import dolfinx.fem.petsc
from textile_fenicsx.common.errors import TextileError, UnresolvedError
from textile_fenicsx.plate.forms import c0ip_bending, foundation, load, tension
from textile_fenicsx.plate.mesh.midsurface import MidSurfaces
from textile_fenicsx.plate.solver.basis import MidAndThickness
from textile_fenicsx.plate.solver.flattening import (
    add_gradient,
    flattening_terms,
    hessian_values,
    law_thickness,
    packing_rows,
    thickness_changes,
)
from textile_fenicsx.plate.solver.linear import (
    DirectSolver,
    SolverError,
    flattening_options,
    mumps_error,
    negative_pivots,
    null_pivots,
)
from textile_fenicsx.plate.solver.numbering import BOTTOM, TOP, Periodicity, seam_facet_tags
from textile_fenicsx.plate.solver.pairs import (
    NONE,
    build_pairs,
    contact_nodes,
    gathered_unknowns,
    initial_gap,
    jacobian_values,
    mould_rows,
    residual_values,
)
from textile_fenicsx.plate.solver.parameters import Compaction, Mould, PlateParameters, SolverOptions
from textile_fenicsx.plate.solver.pattern import FixedPattern

__all__ = ["ContactProblem"]

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


def assemble_plates(ms: MidSurfaces, numbering: Periodicity, pattern: FixedPattern, params: PlateParameters,
                    loads: dict, kf: float) -> tuple[list, PETSc.Vec]:
    """Each yarn's plate matrix into `pattern` (as unknowns), and the maps R_i (per yarn, one per
    surface of unknowns) and the load b0.
    The energies act on z0 + w: their restoring force is -A z0, the assembled matrix times z0
    (the action a(z0, v) as a matrix-vector product; ufl.action took 0.7 s of a satin run). Where
    the yarns flatten, w is the mean of the bottom's and the top's unknowns: A / 4 at each pair of
    them, the load b0 / 2 on each."""
    p = params
    R, b = [], numbering.vector()
    sides = (BOTTOM, TOP)[:numbering.surfaces]
    for y in ms.yarns:
        msh = y.mesh
        dS = ufl.Measure("dS", msh, subdomain_data=seam_facet_tags(y), subdomain_id=1)
        c = dolfinx.fem.Constant
        assert p.Db12 is not None  # PlateParameters sets its default
        Db1, Db2, Db12 = (c(msh, float(v)) for v in (p.Db1, p.Db2, p.Db12))
        u, v = ufl.TrialFunction(y.V), ufl.TestFunction(y.V)
        a = c0ip_bending(u, v, y.d, Db1, Db2, Db12, c(msh, p.alpha), y.dx, dS) \
            + tension(u, v, y.d, c(msh, float(p.sigma1)), y.dx)
        A = dolfinx.fem.petsc.assemble_matrix(dolfinx.fem.form(a))
        A.assemble()
        bi = A.createVecLeft()
        A.mult(y.z0.x.petsc_vec, bi)
        bi.scale(-1.0)
        if y.yarn in loads:  # a number [N/mm^2] or a function of the SpatialCoordinate
            q = loads[y.yarn]
            q = q(ufl.SpatialCoordinate(msh)) if callable(q) else c(msh, float(q))
            f = dolfinx.fem.petsc.assemble_vector(dolfinx.fem.form(load(v, q, y.dx)))
            f.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            bi.axpy(1.0, f)
            f.destroy()
        if kf:
            F = dolfinx.fem.petsc.assemble_matrix(dolfinx.fem.form(foundation(u, v, c(msh, float(kf)), y.dx)))
            F.assemble()
            A.axpy(1.0, F, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
            F.destroy()
        indptr, cols, vals = A.getValuesCSR()
        rows = np.repeat(np.arange(len(indptr) - 1), np.diff(indptr))
        columns = numbering.column_parents(y, cols)
        if len(sides) == 2:
            vals = vals / 4
            bi.scale(0.5)
        for row_side in sides:
            for col_side in sides:
                pattern.add_fixed(numbering.yarn_unknowns(y, rows, row_side),
                                  numbering.unknown(y.yarn, columns, col_side), vals)
        R.append([numbering.yarn_map(y, side) for side in sides])
        for Ri in R[-1]:
            Ri.multTransposeAdd(bi, b, b)
        A.destroy()
        bi.destroy()
    return R, b


class ContactProblem:
    """Assembled operators of one textile's plates and contact pairs."""

    def __init__(self, ms: MidSurfaces, params: PlateParameters = PlateParameters(),
                 options: SolverOptions = SolverOptions(), loads: dict | None = None,
                 foundation_stiffness: float = 0.0, mould: Mould | None = None,
                 compaction: Compaction | None = None):
        self.ms, self.params, self.options, self.mould = ms, params, options, mould
        self.compaction = compaction
        self.exact = options.method == "exact"
        if self.exact and params.Et == 0:
            raise TextileError("Et must be > 0 with the exact contact method: the spring where yarns are apart is "
                               "all that holds a yarn's height against its neighbours (the default is 1e-4 N/mm^3)")
        if mould is not None and not self.exact:
            raise TextileError("a mould needs the exact contact method (its platens are constraints)")
        if compaction is not None and not self.exact:
            raise TextileError("yarns that flatten need the exact contact method (their packing is a constraint)")
        if compaction is not None and mould is None:
            raise TextileError("yarns that flatten need a mould: its platens press them (and hold the translation)")
        self.comm = ms.V.mesh.comm
        self.numbering = numbering = Periodicity(ms, 1 if compaction is None else 2)
        pattern = FixedPattern(self.comm, numbering.start, numbering.n_local)
        self.R, self.b_fixed = assemble_plates(ms, numbering, pattern, params, loads or {}, foundation_stiffness)
        self._translation(foundation_stiffness, mould is not None)
        images = numbering.image_dofs(ms)
        platens = None if mould is None else mould_rows(ms, numbering, images, mould, options.min_gap)
        packing = None if compaction is None else packing_rows(ms, numbering, images, compaction)
        extra = np.concatenate([np.zeros(0, np.int64)] + ([] if platens is None else [platens.unknown])
                               + ([] if packing is None else [packing.top, packing.bottom]))
        self.pairs, (rows, cols), need = build_pairs(ms, numbering, params, self.exact, extra, options.min_gap,
                                                       lumped=compaction is not None)
        self.flattening, self._flat_entries = [], 0
        if compaction is not None:
            self.flattening, (fr, fc) = flattening_terms(ms, numbering, self.R, compaction)
            self._flat_entries = len(fr)
            rows, cols = np.concatenate([rows, fr]), np.concatenate([cols, fc])
        self.nodes = contact_nodes(self.comm, self.pairs, need, images, platens, packing) if self.exact else None
        if self.nodes is not None:
            nr, nc = self.nodes.pattern()
            rows, cols = np.concatenate([rows, nr]), np.concatenate([cols, nc])
        pattern.freeze(rows, cols)
        numbering.release()
        self.pattern, self.need = pattern, need
        self._gather, self._gathered = gathered_unknowns(self.b_fixed, need)
        if self.exact:  # the apart spring is quadratic: it joins the fixed part (K_fixed, b_fixed)
            zero = numbering.vector()
            g0 = self.gaps(zero)
            zero.destroy()
            spring = [jacobian_values(p, g) for p, g in zip(self.pairs, g0)]
            self._pair_entries = int(sum(len(s) for s in spring))
            pattern.absorb(self._variable(spring, 0.0))
            del spring
            self._add_contact(self.b_fixed, [-residual_values(p, g) for p, g in zip(self.pairs, g0)])
        # yarns that flatten: the Newton systems in (w, dt), where the plates appear once (basis.py)
        self.basis = None if compaction is None else MidAndThickness(pattern, numbering)
        self.K_fixed = pattern.matrix()
        self.K = pattern.matrix() if self.basis is None else self.basis.matrix(pattern.values())
        linear = options.linear_options
        self.solver = DirectSolver(self.comm, linear if compaction is None else flattening_options(linear))
        self.factorisations, self._convex_checked, self._largest_weight = 0, -1, 0.0
        diag = self.K_fixed.getDiagonal()
        self._plates_scale = diag.max()[1]  # the plates' (and spring's) largest stiffness [N/mm]
        diag.destroy()

    def renew(self, options: SolverOptions, mould: Mould | None = None) -> None:
        """The problem again, for a solve with these options after the mid-surfaces' thickness and
        contact margins changed (slopes.py, widen_margins), or its mould's platens moved (`mould`,
        for a problem built with one: a compaction's next step): the plates, the pattern, the
        pairs' forms and the direct solver (its analysis) are kept; the pairs' initial gaps and
        margins and the platens' gaps are read again, and for the exact method the apart spring's
        load at them, -T^T J g0, moves by -T^T J (g0_new - g0_old) (J does not depend on g). Where
        the yarns flatten, their relaxed thickness must be the one the problem was built with (the
        compaction law and the packing read it)."""
        if mould is not None and self.mould is None:
            raise ValueError("renew: a mould for a problem built without one: build a new one")
        changed = [not np.array_equal(f.t0.x.array, law_thickness(self.ms.yarns[f.yarn])) for f in self.flattening]
        if self.comm.allreduce(any(changed), op=MPI.LOR):  # (law_thickness is collective: every yarn on every rank)
            raise ValueError("renew: the yarns that flatten changed thickness: build a new problem")
        old = [p.g0 for p in self.pairs]
        self.pairs = [replace(p, g0=g0, margin=margin) for p, (g0, margin) in
                      zip(self.pairs, (initial_gap(self.ms, p.upper, p.lower, options.min_gap) for p in self.pairs))]
        if self.exact:
            self._add_contact(self.b_fixed, [-residual_values(p, p.g0 - g) for p, g in zip(self.pairs, old)])
        if self.nodes is not None:  # the same nodes of the same pairs, platens and packing
            g0 = self.nodes.g0.copy()
            paired = self.nodes.pair >= 0
            gaps = np.concatenate([p.g0 - p.margin for p in self.pairs] + [np.zeros(0)])
            first = np.concatenate([[0], np.cumsum([len(p.g0) for p in self.pairs])])
            g0[paired] = gaps[first[self.nodes.pair[paired]] + self.nodes.at[paired]]
            if self.mould is not None:
                self.mould = self.mould if mould is None else mould
                images = self.numbering.image_dofs(self.ms)
                g0[self.nodes.pair == NONE] = mould_rows(self.ms, self.numbering, images, self.mould,
                                                         options.min_gap).g0
            self.nodes = replace(self.nodes, g0=g0)
        self.options = options
        self.factorisations, self._convex_checked, self._largest_weight = 0, -1, 0.0

    def _translation(self, kf: float, moulded: bool) -> None:
        """The common vertical translation, the energy's null space when there is no foundation
        and no mould: the net load is spread over the area (the reaction a constraint on the
        area-weighted mean of w would give), unknown 0 is pinned in every Newton matrix (`pin`),
        and `displacements` shifts the solution to zero mean."""
        m = self.numbering.vector()
        for y, maps in zip(self.ms.yarns, self.R):
            mi = dolfinx.fem.petsc.assemble_vector(dolfinx.fem.form(ufl.TestFunction(y.V) * y.dx))
            mi.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            if len(maps) == 2:  # m . x: the area-weighted mean of the mid-surfaces' heights
                mi.scale(0.5)
            for R in maps:
                R.multTransposeAdd(mi, m, m)
            mi.destroy()
        self.area_weights, self.area = m, m.sum()
        self.free_translation = not kf and not moulded
        self.pin = 0 if self.free_translation else None
        if self.free_translation:
            self.b_fixed.axpy(-self.b_fixed.sum() / self.area, m)

    def _variable(self, jacobians: list[np.ndarray], c, hessian: np.ndarray | None = None) -> np.ndarray:
        """Variable values in the pattern's order: the pairs' Jacobian entries, the compaction
        energy's Hessian (flattening.py), then the nodes'."""
        parts = list(jacobians) + [np.zeros(0), np.zeros(self._flat_entries) if hessian is None else hessian]
        if self.nodes is not None:
            parts.append(self.nodes.values(np.broadcast_to(c, self.nodes.g0.shape).astype(float)))
        return np.concatenate(parts)

    def _add_contact(self, vec: PETSc.Vec, per_pair: list[np.ndarray]) -> None:
        """vec += T^T r: each pair's values at its dofs (this rank's part), + at u's unknowns and - at l's."""
        rows = [self.need[p.at_u] for p in self.pairs] + [self.need[p.at_l] for p in self.pairs]
        vals = list(per_pair) + [-r for r in per_pair]
        if rows:
            vec.setValues(np.concatenate(rows).astype(PETSc.IntType), np.concatenate(vals),
                          addv=PETSc.InsertMode.ADD_VALUES)
        vec.assemble()

    def add_at(self, vec: PETSc.Vec, rows: np.ndarray, values: np.ndarray) -> None:
        """vec[rows] += values (global rows, any rank's); collective."""
        vec.setValues(rows.astype(PETSc.IntType), values, addv=PETSc.InsertMode.ADD_VALUES)
        vec.assemble()

    def gather(self, x: PETSc.Vec) -> np.ndarray:
        """The unknowns the pairs and the mould need, on this rank, and a 0 after them (where a
        platen's constraint reads the platen's displacement)."""
        self._gather.scatter(x, self._gathered, addv=PETSc.InsertMode.INSERT_VALUES, mode=PETSc.ScatterMode.FORWARD)
        return np.append(self._gathered.getArray(readonly=True), 0.0)

    def gaps(self, x: PETSc.Vec) -> list[np.ndarray]:
        """Every pair's gap at x [mm] (ghost dofs included)."""
        xs = self.gather(x)
        return [p.gap(xs) for p in self.pairs]

    def gradient(self, x: PETSc.Vec, g: list[np.ndarray] | None) -> PETSc.Vec:
        """K_fixed x - b_fixed, plus the contact residual T^T dE_c/dg at gaps g (penalty)."""
        r = self.b_fixed.duplicate()
        self.K_fixed.mult(x, r)
        r.axpy(-1.0, self.b_fixed)
        if not self.exact:
            assert g is not None  # the penalty method's residual depends on the gaps
            self._add_contact(r, [residual_values(p, gp) for p, gp in zip(self.pairs, g)])
        add_gradient(self.flattening, x, r)
        return r

    def energy(self, x: PETSc.Vec, g: list[np.ndarray]) -> float:
        """E(x) up to a constant (the exact method's nodal terms are the algorithm's own)."""
        y = x.duplicate()
        self.K_fixed.mult(x, y)
        fixed = 0.5 * x.dot(y) - self.b_fixed.dot(x)
        y.destroy()
        if self.exact:
            return fixed
        local = 0.0
        for p, gp in zip(self.pairs, g):
            p.fill(gp)
            local += dolfinx.fem.assemble_scalar(p.forms.energy)
        return fixed + self.comm.allreduce(local, op=MPI.SUM)

    def newton_matrix(self, g: list[np.ndarray] | None = None, c_nodes=0.0, at: PETSc.Vec | None = None) -> PETSc.Mat:
        """K = K0 + the contact Jacobian (the spring, or the penalty's at gaps g) + the compaction
        energy's Hessian at unknowns `at` (yarns that flatten) + C^T diag(c_nodes) C, factorised."""
        if self.exact:  # the spring is in the constant part already
            jac = [np.zeros(self._pair_entries)]
        else:
            assert g is not None  # the penalty method's Jacobian depends on the gaps
            jac = [jacobian_values(p, gp) for p, gp in zip(self.pairs, g)]
        hessian = None
        if self.flattening:
            assert at is not None  # the compaction energy's Hessian depends on the thickness
            hessian = hessian_values(self.flattening, at)
        if self.basis is None:
            self.pattern.fill(self.K, self._variable(jac, c_nodes, hessian), pin=self.pin)
        else:  # a mould holds the translation: nothing is pinned
            self.basis.fill(self.K, self.pattern.values(self._variable(jac, c_nodes, hessian)))
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
        """x = K^-1 rhs with K's last factorisation (newton_matrix), checked: converged, finite, no
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
        held_by_nothing = self.params.Et == 0 and negative > 0
        if reason <= 0 or nulls > 0 or held_by_nothing:
            error, hint = SolverError, ("with Et = 0 a yarn that touches no other yarn is held by nothing: give "
                                        "Et > 0" if self.params.Et == 0 else
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
        v, y, Kv = self.b_fixed.duplicate(), self.b_fixed.duplicate(), self.b_fixed.duplicate()
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

    def penetration(self, g: list[np.ndarray]) -> tuple[float, float]:
        """The largest -g at the overlap dofs [mm] (0 when none penetrates) and the volume the gap
        field says, the integral of max(0, -g) over the overlaps [mm^3]."""
        worst, volume = 0.0, 0.0
        for p, gp in zip(self.pairs, g):
            if len(gp):
                worst = max(worst, float(np.max(-gp)))
            p.fill(gp)
            volume += dolfinx.fem.assemble_scalar(p.forms.penetration)
        return self.comm.allreduce(worst, op=MPI.MAX), self.comm.allreduce(volume, op=MPI.SUM)

    def motion(self, dx: PETSc.Vec) -> float:
        """The largest |dx| less the common translation (its area-weighted mean), which moves no
        yarn against another and depends on which unknown is pinned: on the partition [mm]."""
        mean = self.area_weights.dot(dx) / self.area if self.free_translation else 0.0
        local = dx.getArray(readonly=True)
        return self.comm.allreduce(float(np.max(np.abs(local - mean))) if len(local) else 0.0, op=MPI.MAX)

    def displacements(self, x: PETSc.Vec) -> list[dolfinx.fem.Function]:
        """Per yarn w = R_i x, after the common translation is set to zero area-weighted mean."""
        if self.free_translation:
            x.shift(-self.area_weights.dot(x) / self.area)
        w = []
        for y, maps in zip(self.ms.yarns, self.R):
            w.append(dolfinx.fem.Function(y.V, name="w"))
            maps[0].mult(x, w[-1].x.petsc_vec)
            if len(maps) == 2:  # the mid-surface: the mean of the bottom's and the top's
                top = w[-1].x.petsc_vec.duplicate()
                maps[1].mult(x, top)
                w[-1].x.petsc_vec.axpy(1.0, top)
                w[-1].x.petsc_vec.scale(0.5)
                top.destroy()
            w[-1].x.scatter_forward()
        return w

    def thickness_changes(self, x: PETSc.Vec) -> list[dolfinx.fem.Function] | None:
        """Per yarn its thickness change dt [mm] where the yarns flatten, else None."""
        return thickness_changes(self.flattening, x) if self.flattening else None

    def platen_pressure(self, forces: np.ndarray) -> float | None:
        """A mould's pressure on the fabric [N/mm^2 = MPa]: the bottom platen's force (the sum of its
        nodes' forces) over the cell's area; None without a mould."""
        if self.mould is None or self.nodes is None:
            return None
        n = self.nodes
        bottom = (n.pair == NONE) & (n.rows_l == NONE)
        total = self.comm.allreduce(float(np.sum(forces[bottom])), op=MPI.SUM)
        cell = self.ms.projected.cell
        assert cell is not None  # projected meshes are made with their cell
        return total / cell.area

    def fields(self, g: list[np.ndarray], active: list[np.ndarray]) -> tuple[list, list]:
        """Per yarn, its gap to the yarn below [mm] (0 where none is) and where contact is active (1),
        for output. The owner of a dof may hold no cell of its pair: the values go to the owners
        (the largest, from -inf where a rank has none), then to the ghosts."""
        gaps, states = [], []
        for y in self.ms.yarns:
            gaps.append(dolfinx.fem.Function(y.V, name="gap_below"))
            gaps[-1].x.array[:] = -np.inf
            states.append(dolfinx.fem.Function(y.V, name="contact"))
        for p, gp, a in zip(self.pairs, g, active):
            gaps[p.upper].x.array[p.dofs] = gp
            states[p.upper].x.array[p.dofs] = a.astype(float)
        for f in gaps + states:
            f.x.petsc_vec.ghostUpdate(addv=PETSc.InsertMode.MAX_VALUES, mode=PETSc.ScatterMode.REVERSE)
            f.x.scatter_forward()
        for f in gaps:
            f.x.array[np.isneginf(f.x.array)] = 0.0
        return gaps, states

    def destroy(self) -> None:
        """Free the PETSc objects (the factors first)."""
        self.solver.destroy()
        for obj in (self.K, self.K_fixed, self.b_fixed, self.area_weights, self._gather, self._gathered,
                    *(R for maps in self.R for R in maps)):
            obj.destroy()
