"""The contact iterations: Newton steps on a convex energy.

exact (default): no penetration at the overlap nodes. The energy of the plates (and the spring
that holds yarns together where they are apart) is quadratic, the constraints g_i = g0_i +
(x_u - x_l)_i >= 0 (a mould's: g_i = g0_i +- x_i, a platen in one yarn's place) are linear: a
convex QP, solved by a primal-dual interior-point method (Mehrotra's predictor-corrector) with
nodal slacks s and forces lam. Every step follows a smooth central path s lam = mu -> 0: nothing
in it is a discrete decision, so round-off cannot switch it between branches (active-set
methods flip nodes that sit at zero gap with zero force, and on plates whole contact areas are
like that: the pressure gathers at their edges) and the same
problem takes the same steps on any partition and under any load. It stops when a step that the
boundary did not cut short moves no point by more than displacement_tol and no node penetrates by
more than penetration_tol.

penalty (the paper's): the contact energy 1/2 k(g) g^2 integrated over the overlaps, k = Ec where
g < 0; Newton steps with the contact states at the quadrature points, halved until the energy
falls; stops when the gradient is at round-off level (a state flipping at zero gap changes
neither the energy nor the gradient, so it cannot keep the iteration going).
"""

import logging
import time
from dataclasses import dataclass, field

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from textile_fenicsx.plate.solver.flattening import thinnest_stack
from textile_fenicsx.plate.solver.pairs import NONE
from textile_fenicsx.plate.solver.problem import ContactProblem

__all__ = ["Outcome", "solve_exact", "solve_penalty"]

log = logging.getLogger(__name__)

# penalty: relative gradient below which a Newton iterate counts as the minimiser (the direct
# solves reach ~1e-14 of the force scale; 1e-10 leaves room for the conditioning of hard contact)
GRADIENT_RTOL = 1e-10
# interior point: the start's spring (a fraction of the plates' nodal stiffness; iteration counts
# moved by one or two over 1e-3..1 on the reference models), how close to the boundary a step
# may go, and the largest nodal weight lam / s (relative to the node's stiffness). A capped node
# moves 1e-8 of its force's worth from where the uncapped step would put it; at 1e6 that error
# kept the iterates from settling (the orthogonal weave and a free-edge coupon wandered for 100
# steps), at 1e10 round-off in the factor of the pinned SPD matrix read as null pivots
START_RATIO = 1e-3
FRACTION_TO_BOUNDARY = 0.995
MAX_WEIGHT = 1e8
# the cap where the yarns flatten (a compaction law; a mould holds the translation, nothing is
# pinned). At 1e8 the capped directions left the forces out of equilibrium when the steps had
# settled: the plain weave pressed to Vf 0.5 ended its steps with a dual residual up to the size
# of the internal forces (0.41 N against 0.41), its platens' forces 8.3 and 9.1 N apart, and its
# pressure 0.43 or 0.55 MPa depending on the start; at 1e12 the residual is 1e-9 N, the platens
# balance to 1e-9 and every start gives 0.656 MPa
MAX_WEIGHT_PRESSED = 1e12
# where the yarns flatten, the platens' pressure is read from the forces: a solve that settles
# measures how far they are from equilibrium, its dual residual (K x - f - C^T lam) over the
# largest internal force, and above this the compaction warns that its pressure is uncertain.
# Not a condition to stop: where yarns are packed to the maximum under a pair (the polygon
# weaves), or a platen node's slack fell to round-off before its force grew (TexGen's refined
# jammed plain weave), it stays at 0.8-2 however long the iteration goes on (100 steps). Such
# forces are refitted to equilibrium at the settled unknowns (recover_forces): over `make
# sweep-compaction` every step then balances to 3e-7 or better, and the refined jammed plain
# weave's pressure at Vf 0.5 is 1.18565 MPa from 1, 2, 3 or 4 steps (1.1846, 1.1076, 1.1137 and
# 1.1139 before)
DUAL_RTOL = 1e-6
# where a compaction step settles out of balance, its forces are refitted to equilibrium
# (_InteriorPoint.recover_forces): rounds of opening constraints whose fitted force is negative,
# and the conjugate gradients' tolerance and cap on each fit
RECOVERY_ROUNDS, RECOVERY_RTOL, RECOVERY_ITERATIONS = 5, 1e-12, 2000
# a warm start (from a related problem's solution) keeps its slacks at least this far from 0 [mm]
WARM_GAP = 1e-5
# steps in a row that move nothing while nodes still penetrate: the constraints cannot all hold
STALLED_STEPS, STALLED_STEP = 5, 1e-6


@dataclass
class Outcome:
    """What an iteration ends with: the unknowns, per pair the gap and where contact is active."""

    x: PETSc.Vec
    gaps: list
    active: list
    iterations: int
    updates: int
    converged: bool
    reason: str
    history: list = field(default_factory=list)
    forces: object = None  # exact method: the nodal contact forces [N]


def _global_max(comm, values: np.ndarray) -> float:
    return comm.allreduce(float(np.max(values)) if len(values) else 0.0, op=MPI.MAX)


def _step_to_boundary(v: np.ndarray, dv: np.ndarray) -> float:
    """The largest alpha <= 1 with v + alpha dv >= 0 (v > 0), on this rank."""
    down = dv < 0
    return float(min(1.0, np.min(-v[down] / dv[down]))) if np.any(down) else 1.0


class _InteriorPoint:
    """Mehrotra's predictor-corrector for  min E(x)  subject to  g(x) = g0 + C x >= 0  at the nodes,
    with slacks s = g (s > 0) and nodal forces lam > 0, s lam -> 0 along the central path. Each
    step factorises K_fixed + C^T diag(lam / s) C once and solves with it twice."""

    def __init__(self, problem: ContactProblem, x0=None):
        nodes = problem.nodes
        assert nodes is not None  # the exact method's problem has its constrained nodes
        self.problem, self.nodes, self.comm = problem, nodes, problem.comm
        self.count = max(self.comm.allreduce(len(nodes.g0), op=MPI.SUM), 1)
        diag = problem.K_fixed.getDiagonal()
        dg = problem.gather(diag)
        diag.destroy()
        self.k = np.abs(dg[nodes.at_u]) + np.abs(dg[nodes.at_l])  # the plates' stiffness at each node [N/mm]
        self.cap = MAX_WEIGHT_PRESSED if problem.compaction is not None else MAX_WEIGHT
        # start: x = 0 (or x0), slacks a little above the gaps there, forces of a soft spring over
        # that distance
        self.x, self.dx = problem.b_fixed.duplicate(), problem.b_fixed.duplicate()
        self.x.set(0.0)
        if x0 is None:
            tau = max(self.max(-nodes.g0), problem.options.penetration_tol * 1e3)
            self.s = np.maximum(nodes.g0, 0.0) + tau
            self.lam = START_RATIO * self.k * tau
        else:  # warm: the earlier unknowns and forces; the slacks at the new gaps, shifted (as the
            # cold start's) by the deepest penetration there, so that no node starts nearer its
            # boundary than it penetrates (slacks of WARM_GAP at nodes 3.6 um deep held the first
            # ten steps of satin4's second solve to 1e-3..6e-2 of a step); constraints the earlier
            # problem did not have (a mould's) start with a soft spring
            x_start, lam_start = x0
            self.x.getArray()[:] = x_start
            if problem.mould is not None:
                self._centre()
            g = self.gaps(self.x)
            shift = max(self.max(-g), WARM_GAP)
            self.s = np.maximum(g, 0.0) + shift
            lam_start = np.concatenate([lam_start, np.zeros(len(self.s) - len(lam_start))])
            # the forces' floor: a compaction step's start is the step before, which its closer
            # platens penetrate (0.04 mm on satin4 at seed 0.5): its forces get the cold start's
            # soft spring over that shift, not over WARM_GAP (to Vf 0.55 in 4 steps: satin4 70
            # Newton steps against 82, twill22 66 against 77, the same pressures to 1e-9);
            # elsewhere (the relaxed second solve, 4e-3 mm) WARM_GAP's (a floor over the shift
            # took satin4's one step more)
            floor = shift if problem.compaction is not None else WARM_GAP
            self.lam = np.maximum(lam_start, START_RATIO * self.k * floor)

    def _centre(self) -> None:
        """Translate the start to the middle of the mould: the same distance (or overlap) to both
        platens."""
        nodes, g = self.nodes, self.gaps(self.x)
        bottom, top = (nodes.pair == NONE) & (nodes.rows_l == NONE), (nodes.pair == NONE) & (nodes.rows_u == NONE)
        self.x.shift((-self.max(-g[top]) + self.max(-g[bottom])) / 2)

    def max(self, v: np.ndarray) -> float:
        return _global_max(self.comm, v)

    def imbalance(self, lam: np.ndarray | None = None) -> float:
        """The dual residual K x - f - C^T lam over the internal forces K x - f, in the largest
        entry of each [-] (collective; lam: the interior point's own by default)."""
        r = self.problem.gradient(self.x, None)
        forces = r.norm(PETSc.NormType.NORM_INFINITY)
        self.add_transpose(r, self.lam if lam is None else lam, -1.0)
        out = r.norm(PETSc.NormType.NORM_INFINITY) / max(forces, 1e-300)
        r.destroy()
        return out

    def recover_forces(self, before: float) -> float:
        """Where a settled solve's forces are out of balance (a node's slack fell to round-off
        before its force grew, or yarns are packed to the maximum under a pair), the forces of
        the closed constraints (lam > k s, as `_ended` counts them) refitted to equilibrium at the
        settled x: the least-squares lam_A of C_A^T lam_A = K x - f, by conjugate gradients on
        C_A C_A^T (each row of C is +-1 at two unknowns at most), constraints whose fitted force
        is negative opened and the fit repeated (RECOVERY_ROUNDS). Kept, in self.lam, where it
        balances better than the interior point's forces, whose imbalance is `before`. Returns the
        imbalance (`imbalance`) after (collective)."""
        r = self.problem.gradient(self.x, None)
        rhs = self._times_c(r)  # C (K x - f)
        r.destroy()
        closed = self.lam > self.k * self.s
        for _ in range(RECOVERY_ROUNDS):
            fitted = self._least_squares(rhs, closed)
            lam = np.where(closed, np.maximum(fitted, 0.0), self.lam)
            negative = self.comm.allreduce(int(np.sum(closed & (fitted < 0))), op=MPI.SUM)
            if not negative:
                break
            closed = closed & (fitted >= 0)
        after = self.imbalance(lam)
        if after < before:
            self.lam = lam
        return min(before, after)

    def _times_c(self, vec: PETSc.Vec) -> np.ndarray:
        """C vec at this rank's constraints (the gaps' linear part)."""
        return self.gaps(vec) - self.nodes.g0

    def _least_squares(self, rhs: np.ndarray, on: np.ndarray) -> np.ndarray:
        """lam on the constraints `on` (0 elsewhere) solving C_on C_on^T lam = rhs on them (rhs: C
        applied to the forces K x - f), by conjugate gradients to RECOVERY_RTOL (collective)."""
        work = self.problem.b_fixed.duplicate()

        def normal(v):  # C_on C_on^T v
            work.zeroEntries()
            self.add_transpose(work, np.where(on, v, 0.0))
            return np.where(on, self._times_c(work), 0.0)

        def dot(a, b):
            return self.comm.allreduce(float(np.dot(a, b)), op=MPI.SUM)

        lam = np.zeros(len(rhs))
        res = np.where(on, rhs, 0.0)
        d, rr = res.copy(), dot(res, res)
        stop = (RECOVERY_RTOL ** 2) * rr
        for _ in range(RECOVERY_ITERATIONS):
            if rr <= stop or rr == 0.0:
                break
            q = normal(d)
            a = rr / dot(d, q)
            lam += a * d
            res -= a * q
            rr, previous = dot(res, res), rr
            d = res + (rr / previous) * d
        work.destroy()
        return lam

    def mean(self, v: np.ndarray) -> float:
        return self.comm.allreduce(float(np.sum(v)), op=MPI.SUM) / self.count

    def gaps(self, x: PETSc.Vec) -> np.ndarray:
        return self.nodes.gap(self.problem.gather(x))

    def add_transpose(self, vec: PETSc.Vec, v: np.ndarray, scale: float = 1.0) -> None:
        """vec += scale C^T v."""
        rows, values = self.nodes.transpose_rows(v)
        self.problem.add_at(vec, rows, scale * values)

    def step(self, it: int) -> dict:
        """One predictor-corrector step; what it did."""
        problem, s, lam = self.problem, self.s, self.lam
        g = self.gaps(self.x)
        rd = problem.gradient(self.x, None)  # dual residual K x - f - C^T lam
        self.add_transpose(rd, lam, -1.0)
        rp = g - s
        mu = self.mean(s * lam)
        w = np.minimum(lam / s, self.cap * self.k)  # capped: a closed node's weight grows like 1/mu
        problem.newton_matrix(c_nodes=w, at=self.x)

        def direction(rc):
            """(ds, dlam), with dx in self.dx, for the complementarity residual rc = s lam - target."""
            rhs = rd.copy()
            rhs.scale(-1.0)
            self.add_transpose(rhs, rc / s + w * rp, -1.0)
            problem.solve(rhs, self.dx, f"contact iteration {it}")
            rhs.destroy()
            xs = problem.gather(self.dx)
            ds = xs[self.nodes.at_u] - xs[self.nodes.at_l] + rp
            return ds, -(rc + lam * ds) / s

        def longest(ds, dl):
            return self.comm.allreduce(min(_step_to_boundary(s, ds), _step_to_boundary(lam, dl)), op=MPI.MIN)

        ds, dl = direction(s * lam)  # the affine step, then the centred corrector
        alpha = longest(ds, dl)
        sigma = (self.mean((s + alpha * ds) * (lam + alpha * dl)) / mu) ** 3 if mu > 0 else 0.0
        ds, dl = direction(s * lam + ds * dl - sigma * mu)
        alpha = min(1.0, FRACTION_TO_BOUNDARY * longest(ds, dl))
        self.x.axpy(alpha, self.dx)
        self.s, self.lam = s + alpha * ds, lam + alpha * dl
        rd.destroy()
        motion = problem.motion(self.dx)
        return dict(iteration=it, mu=mu, max_penetration=self.max(-g), step=alpha, sigma=sigma,
                    moved_mm=alpha * motion, direction_mm=motion)


def solve_exact(problem: ContactProblem, x0=None) -> Outcome:
    """The exact method (module docstring): interior-point steps until one that is not held back
    by the boundary moves no point by more than displacement_tol, and no node penetrates."""
    opts = problem.options
    ip = _InteriorPoint(problem, x0)
    history, stalled, good = [], 0, np.inf
    for it in range(1, opts.max_iterations + 1):
        t0 = time.perf_counter()
        line = ip.step(it)
        g = ip.gaps(ip.x)
        line.update(max_penetration=ip.max(-g), time_s=time.perf_counter() - t0)
        history.append(line)
        log.info("contact step %3d: max penetration %.3e mm, moved %.2e mm, step %.3g, mu %.2e, %.2f s", it,
                 line["max_penetration"], line["moved_mm"], line["step"], line["mu"], line["time_s"])
        # done: a full step (not cut short by the boundary) moved nothing by more than the
        # tolerance; or a step is cut short at the precision floor, after a full step or along a
        # direction that moved or would move nothing by more than ten times the tolerance: the
        # iterates are at the precision of double arithmetic (the closed nodes' lam / s), and
        # further steps only lose it (twill31 at seed 0.5, reading the last full step only: a full
        # step of 1.15e-5 mm, then a direction of 4.3e-6 mm cut to 1.8e-7 of itself at mu 2e-13,
        # then 30 steps wandering with mu up to 2e-5 before settling again)
        floor = line["step"] < 0.1 and min(good, line["direction_mm"]) <= 10 * opts.displacement_tol
        good = line["moved_mm"] if line["step"] >= 0.5 else good
        if line["max_penetration"] <= opts.penetration_tol and (good <= opts.displacement_tol or floor):
            if problem.compaction is not None:  # the platens' pressure is read from the forces
                line["imbalance"] = ip.imbalance()
                if line["imbalance"] > DUAL_RTOL and not floor and good > (opts.settle_tol or np.inf):
                    continue  # settled, but not its forces: on to settle_tol (a compaction's steps)
                if line["imbalance"] > DUAL_RTOL:
                    line["imbalance_settled"] = line["imbalance"]
                    line["imbalance"] = ip.recover_forces(line["imbalance_settled"])
                    log.info("contact: the settled forces, out of balance by %.1e of the largest, refitted to "
                             "equilibrium: %.1e", line["imbalance_settled"], line["imbalance"])
            at_floor = (f"; the next direction ({line['direction_mm']:.1e} mm) was cut to {line['step']:.1e} of "
                        "itself at the precision floor" if floor and good > opts.displacement_tol else "")
            return _ended(problem, ip, it, history, True,
                          f"converged: the last full step moved {good:.1e} mm{at_floor}, no node penetrates by "
                          f"more than {max(line['max_penetration'], 0):.1e} mm (tolerances "
                          f"{opts.displacement_tol:g}, {opts.penetration_tol:g} mm)"
                          + (f", its forces out of balance by {line['imbalance']:.1e} of the largest"
                             if "imbalance" in line else ""))
        # the boundary cuts every step to nothing while nodes still penetrate: no position of the
        # yarns satisfies every contact
        stalled = stalled + 1 if line["step"] <= STALLED_STEP and line["max_penetration"] > opts.penetration_tol else 0
        if stalled >= STALLED_STEPS:
            return _ended(problem, ip, it, history, False, _infeasible(problem, g))
    reason = (f"the contact iteration reached its cap of {opts.max_iterations} steps (largest penetration "
              f"{history[-1]['max_penetration']:.2e} mm, last step moved {history[-1]['moved_mm']:.1e} mm)")
    if problem.compaction is not None and history[-1]["max_penetration"] > opts.penetration_tol:
        # an interior point does not stall on yarns pressed beyond their packing: it keeps moving
        reason = f"{reason}: {_infeasible(problem, ip.gaps(ip.x))}"
    return _ended(problem, ip, opts.max_iterations, history, False, reason)


def _infeasible(problem: ContactProblem, g: np.ndarray) -> str:
    """The message for contact constraints that cannot all hold, naming the worst place."""
    nodes, comm = problem.nodes, problem.comm
    assert nodes is not None  # the exact method's
    k = int(np.argmin(g)) if len(g) else -1
    worst = (float(-g[k]), nodes.pair[k], nodes.at[k]) if k >= 0 else (-np.inf, -1, -1)
    pen, pair, at = max(comm.allgather(worst), key=lambda w: w[0])
    where = ""
    if comm.rank == comm.allgather(worst).index(max(comm.allgather(worst), key=lambda w: w[0])) and pair >= 0:
        p = problem.pairs[pair]
        y = problem.ms.yarns[p.upper]
        xy = y.V.tabulate_dof_coordinates()[p.dofs[at], :2]
        model = problem.ms.projected.textile
        assert model is not None  # a textile's mesh (plate_mesh's plates have none)
        names = [t.name for t in model.yarns]
        where = (f" between {names[p.upper]} (yarn {p.upper}) above and {names[p.lower]} (yarn {p.lower}) below "
                 f"at ({xy[0]:.3f}, {xy[1]:.3f}) mm")
    where = max(comm.allgather(where), key=len)
    if problem.compaction is not None and problem.mould is not None:
        least, (x, y) = thinnest_stack(problem.ms, problem.compaction)
        if least > problem.mould.thickness - 2 * problem.options.min_gap:
            return (f"the yarns cannot be pressed into the mould's {problem.mould.thickness:.4g} mm: packed to the "
                    f"maximum fibre fraction {problem.compaction.phi_max:.4g} of the compaction law, the yarns "
                    f"stacked at ({x:.3f}, {y:.3f}) mm are still {least:.4g} mm thick (give a thicker mould or a lower "
                    "fibre volume fraction)")
    if problem.mould is not None:
        return (f"no position of the yarns keeps every contact inside the mould: {pen:.3g} mm of penetration "
                f"remain{where or ' at a platen'}; the mould ({problem.mould.thickness:.4g} mm) is thinner than the "
                "yarns stacked there, or the stacking order of the model contradicts itself (give a thicker mould)")
    return (f"no position of the yarns keeps every contact: {pen:.3g} mm of penetration remain{where}; the "
            "stacking order of the model contradicts itself there (check the yarns' heights)")


def _ended(problem: ContactProblem, ip: _InteriorPoint, it, history, converged, reason) -> Outcome:
    """The outcome; a node is in contact where its force exceeds its gap's worth of its stiffness."""
    nodes = problem.nodes
    assert nodes is not None  # the exact method's
    g = problem.gaps(ip.x)
    active = [np.zeros(len(gp), bool) for gp in g]
    closed = ip.lam > ip.k * ip.s
    for k, a in enumerate(active):
        a[nodes.at[(nodes.pair == k) & closed]] = True
    ip.dx.destroy()
    out = Outcome(ip.x, g, active, it, 0, converged, reason, history)
    out.forces = ip.lam
    return out


def solve_penalty(problem: ContactProblem) -> Outcome:
    """The paper's penalty method (module docstring)."""
    opts, comm = problem.options, problem.comm
    x, d, x_old = (problem.b_fixed.duplicate() for _ in range(3))
    x.set(0.0)
    g = problem.gaps(x)
    energy = problem.energy(x, g)
    scale = max(problem.b_fixed.norm(), 1e-300)
    history: list[dict] = []
    state = _states(g)
    for it in range(1, opts.max_iterations + 1):
        t0 = time.perf_counter()
        grad = problem.gradient(x, g)
        res = grad.norm() / scale
        if res <= GRADIENT_RTOL and it > 1:
            grad.destroy()
            return Outcome(x, g, [gp < 0 for gp in g], it - 1, 0, True,
                           f"converged: gradient {res:.1e} of the force scale", history)
        problem.newton_matrix(g)
        grad.scale(-1.0)
        problem.solve(grad, d, f"contact iteration {it}")
        grad.destroy()
        x.copy(x_old)
        t = 1.0
        while True:  # halve the step until the energy falls (undamped, the states can cycle)
            x_old.copy(x)
            x.axpy(t, d)
            g = problem.gaps(x)
            trial = problem.energy(x, g)
            if trial <= energy + 1e-12 * (abs(energy) + abs(trial)):
                break
            t /= 2
            if t < 1e-12:
                return Outcome(x, g, [gp < 0 for gp in g], it, 0, False,
                               f"the damped contact step found no lower energy at iteration {it}", history)
        energy, new = trial, _states(g)
        changed = comm.allreduce(int(np.sum(new != state)), op=MPI.SUM)
        state = new
        pen = _global_max(comm, np.concatenate([-gp for gp in g] + [np.zeros(1)]))
        history.append(dict(iteration=it, active=comm.allreduce(int(np.sum(new)), op=MPI.SUM), changed=changed,
                            max_penetration=pen, residual=res, step=t, energy=energy,
                            time_s=time.perf_counter() - t0))
        log.info("contact step %3d: active %6d, changed %5d, max penetration %.3e mm, residual %.2e, step %.3g, "
                 "%.2f s", it, history[-1]["active"], changed, pen, res, t, history[-1]["time_s"])
    return Outcome(x, g, [gp < 0 for gp in g], opts.max_iterations, 0, False,
                   f"the contact iteration reached its cap of {opts.max_iterations} steps", history)


def _states(g: list[np.ndarray]) -> np.ndarray:
    """Where the gap is closed, at the overlap dofs (the penalty's states, for the log)."""
    return np.concatenate([gp < 0 for gp in g] + [np.zeros(0, bool)])
