"""The assembled problem: plates, the pinned translation and the contact pairs over the unknowns.

Energy (DESIGN.md 5), with x the unknowns:
    E(x) = 1/2 x^T K0 x - b0^T x + sum_pairs E_c(g_p),   g_p = g0_p + T_p x,
K0 the plates (each yarn's bending + tension on its submesh, reduced by the periodic map R_i:
K0 = sum R_i^T A_i R_i, plates.py), b0 their restoring force -A_i z0_i (and any load), E_c the
contact energy of forms/contact.py. For the exact method E_c is quadratic (the apart spring) and
joins the fixed part: K_fixed = K0 + sum T^T J T, b_fixed = b0 - sum T^T J g0.
E does not change when every yarn rises by the same amount (without a foundation or a mould): the
Newton matrices pin one unknown instead, so that they are symmetric positive definite (MUMPS'
Cholesky without pivoting, whatever the interior point's weights), and the solution is shifted
to zero mean afterwards (plates.Translation). A mould holds that translation itself: every node
has its platens' weights in the interior point's matrix, and nothing is pinned.
`ContactProblem` evaluates the energy (its gradient, value and Newton matrix at the unknowns); its
Newton matrix is factorised and solved by its NewtonSystem (system.py), and a solution is read out
by readout.py. It owns the PETSc objects it makes (K_fixed, the vectors, and through its
NewtonSystem K and the direct solver) and frees them in `destroy()`.
"""

from dataclasses import replace

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

import dolfinx
from textile_fenicsx.common.errors import TextileError
from textile_fenicsx.plate.mesh.midsurface import MidSurfaces
from textile_fenicsx.plate.solver import readout
from textile_fenicsx.plate.solver.basis import MidAndThickness
from textile_fenicsx.plate.solver.flattening import (
    add_gradient,
    flattening_terms,
    hessian_values,
    law_thickness,
    packing_rows,
    thickness_changes,
)
from textile_fenicsx.plate.solver.linear import flattening_options
from textile_fenicsx.plate.solver.numbering import Periodicity
from textile_fenicsx.plate.solver.pairs import (
    build_pairs,
    contact_nodes,
    gathered_unknowns,
    initial_gap,
    jacobian_values,
    mould_rows,
    renewed_nodes,
    residual_values,
)
from textile_fenicsx.plate.solver.parameters import Compaction, Mould, PlateParameters, SolverOptions
from textile_fenicsx.plate.solver.pattern import FixedPattern
from textile_fenicsx.plate.solver.plates import assemble_plates, common_translation
from textile_fenicsx.plate.solver.system import NewtonSystem

__all__ = ["ContactProblem", "check_combination", "variable_terms"]


def check_combination(params: PlateParameters, options: SolverOptions, mould: Mould | None,
                      compaction: Compaction | None) -> None:
    """Refuse (TextileError) what the contact method cannot do: the exact method needs the apart
    spring (Et > 0); a mould and yarns that flatten need the exact method, and yarns that flatten
    a mould."""
    exact = options.method == "exact"
    if exact and params.Et == 0:
        raise TextileError("Et must be > 0 with the exact contact method: the spring where yarns are apart is "
                           "all that holds a yarn's height against its neighbours (the default is 1e-4 N/mm^3)")
    if mould is not None and not exact:
        raise TextileError("a mould needs the exact contact method (its platens are constraints)")
    if compaction is not None and not exact:
        raise TextileError("yarns that flatten need the exact contact method (their packing is a constraint)")
    if compaction is not None and mould is None:
        raise TextileError("yarns that flatten need a mould: its platens press them (and hold the translation)")


def variable_terms(ms: MidSurfaces, numbering: Periodicity, params: PlateParameters, options: SolverOptions,
                   R: list, mould: Mould | None, compaction: Compaction | None) -> tuple:
    """The terms of the Newton matrices that change with the iterate, in the order of their values
    (ContactProblem._variable): the contact pairs, the compaction energy's where the yarns flatten
    (flattening.py, with its count of entries), then the exact method's constrained nodes (the
    pairs', a mould's platens' and the maximum packing's; None for the penalty method); the
    unknowns the pairs and the nodes read (`need`); and the (rows, columns) of all their entries.
    R: the plates' maps (plates.assemble_plates)."""
    exact = options.method == "exact"
    images = numbering.image_dofs(ms)
    platens = None if mould is None else mould_rows(ms, numbering, images, mould, options.min_gap)
    packing = None if compaction is None else packing_rows(ms, numbering, images, compaction)
    extra = np.concatenate([np.zeros(0, np.int64)] + ([] if platens is None else [platens.unknown])
                           + ([] if packing is None else [packing.top, packing.bottom]))
    pairs, (rows, cols), need = build_pairs(ms, numbering, params, exact, extra, options.min_gap,
                                            lumped=compaction is not None)
    flattening: list = []
    flat_entries = 0
    if compaction is not None:
        flattening, (fr, fc) = flattening_terms(ms, numbering, R, compaction)
        flat_entries = len(fr)
        rows, cols = np.concatenate([rows, fr]), np.concatenate([cols, fc])
    nodes = contact_nodes(ms.V.mesh.comm, pairs, need, images, platens, packing) if exact else None
    if nodes is not None:
        nr, nc = nodes.pattern()
        rows, cols = np.concatenate([rows, nr]), np.concatenate([cols, nc])
    return pairs, flattening, flat_entries, nodes, need, (rows, cols)


class ContactProblem:
    """Assembled operators of one textile's plates and contact pairs."""

    def __init__(self, ms: MidSurfaces, params: PlateParameters = PlateParameters(),
                 options: SolverOptions = SolverOptions(), loads: dict | None = None,
                 foundation_stiffness: float = 0.0, mould: Mould | None = None,
                 compaction: Compaction | None = None):
        check_combination(params, options, mould, compaction)
        self.ms, self.params, self.options, self.mould = ms, params, options, mould
        self.compaction = compaction
        self.exact = options.method == "exact"
        self.comm = ms.V.mesh.comm
        self.numbering = numbering = Periodicity(ms, 1 if compaction is None else 2)
        pattern = FixedPattern(self.comm, numbering.start, numbering.n_local)
        self.R, self.b_fixed = assemble_plates(ms, numbering, pattern, params, loads or {}, foundation_stiffness)
        self.translation = common_translation(ms, numbering, self.R, self.b_fixed, foundation_stiffness,
                                              mould is not None)
        self.pairs, self.flattening, self._flat_entries, self.nodes, need, (rows, cols) = variable_terms(
            ms, numbering, params, options, self.R, mould, compaction)
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
        linear = options.linear_options
        self.system = NewtonSystem(self.comm, pattern, self.basis, self.translation.pin,
                                   linear if compaction is None else flattening_options(linear), params.Et,
                                   self.K_fixed, self.b_fixed)
        self.K, self.solver = self.system.K, self.system.solver  # the Newton matrix and its direct solver

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
        if mould is not None:  # (a problem built with a mould: checked above)
            self.mould = mould
        if self.nodes is not None:  # the same nodes of the same pairs, platens and packing
            self.nodes = renewed_nodes(self.ms, self.numbering, self.nodes, self.pairs, self.mould, options.min_gap)
        self.options = options
        self.system.reset()

    @property
    def factorisations(self) -> int:
        """Factorisations of the Newton matrix since the problem was built or renewed."""
        return self.system.factorisations

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
        return self.system.factor(self._variable(jac, c_nodes, hessian), c_nodes)

    def hold_pin(self, rhs: PETSc.Vec) -> None:
        """Set the pinned unknown's entry of a right-hand side to 0 (NewtonSystem.hold_pin)."""
        self.system.hold_pin(rhs)

    def solve(self, rhs: PETSc.Vec, x: PETSc.Vec, what: str) -> None:
        """x = K^-1 rhs with K's last factorisation (newton_matrix), checked (NewtonSystem.solve)."""
        self.system.solve(rhs, x, what)

    def motion(self, dx: PETSc.Vec) -> float:
        """The largest |dx| less the common translation [mm] (Translation.motion)."""
        return self.translation.motion(dx)

    def penetration(self, g: list[np.ndarray]) -> tuple[float, float]:
        """The largest -g at the overlap dofs [mm] and the penetration volume [mm^3] (readout.penetration)."""
        return readout.penetration(self.comm, self.pairs, g)

    def displacements(self, x: PETSc.Vec) -> list[dolfinx.fem.Function]:
        """Per yarn w = R_i x [mm], x shifted to zero mean first (readout.displacements)."""
        return readout.displacements(self.ms, self.R, self.translation, x)

    def thickness_changes(self, x: PETSc.Vec) -> list[dolfinx.fem.Function] | None:
        """Per yarn its thickness change dt [mm] where the yarns flatten, else None."""
        return thickness_changes(self.flattening, x) if self.flattening else None

    def platen_pressure(self, forces: np.ndarray) -> float | None:
        """A mould's pressure on the fabric [N/mm^2 = MPa] (readout.platen_pressure); None without a mould."""
        if self.mould is None or self.nodes is None:
            return None
        return readout.platen_pressure(self.comm, self.ms, self.nodes, forces)

    def fields(self, g: list[np.ndarray], active: list[np.ndarray]) -> tuple[list, list]:
        """Per yarn its gap to the yarn below [mm] and its contact state, for output (readout.fields)."""
        return readout.fields(self.ms, self.pairs, g, active)

    def destroy(self) -> None:
        """Free the PETSc objects (the factors first)."""
        self.system.destroy()
        for obj in (self.K_fixed, self.b_fixed, self.translation.weights, self._gather, self._gathered,
                    *(R for maps in self.R for R in maps)):
            obj.destroy()
