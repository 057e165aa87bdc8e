"""Plate + tension + contact solve of all yarns at once (DESIGN.md sections 5, 6 and 9).

One module per idea:
- parameters: PlateParameters, Compaction, Mould, SolverOptions, Solution;
- numbering: the unknowns (Periodicity, the one owner of the periodic numbering) and seam facets;
- pattern: the combined matrix's fixed CSR pattern (FixedPattern);
- pairs: contact pairs as data, their forms derived from the contact energy; the exact method's
  constrained nodes (the pairs', a mould's platens');
- flattening: yarns whose thickness is an unknown, held by their compaction law;
- basis: their Newton systems solved in mid-height and thickness change (w, dt);
- plates: the plates' matrix and load over the unknowns, and the common vertical translation;
- problem: ContactProblem, the assembled energy: its gradient, value and Newton matrix at the
  unknowns (owns K_fixed and the vectors);
- system: NewtonSystem, the Newton matrix factorised and its solves checked (owns K and the direct
  solver);
- readout: a solution's displacements, gap and contact fields, penetration and platen pressure;
- newton: the iterations (exact contact, the default; the paper's penalty);
- linear: PETSc options as dicts, the direct solver and its checks.
"""

import logging
import time

import numpy as np

from textile_fenicsx.common.memory import release_freed_memory
from textile_fenicsx.plate.mesh.midsurface import MidSurfaces
from textile_fenicsx.plate.solver.linear import DIRECT_LDLT, DIRECT_LU, OUT_OF_CORE, SolverError, check_converged
from textile_fenicsx.plate.solver.newton import solve_exact, solve_penalty
from textile_fenicsx.plate.solver.parameters import (
    METHODS,
    Compaction,
    Mould,
    PlateParameters,
    Solution,
    SolverOptions,
)
from textile_fenicsx.plate.solver.problem import ContactProblem

__all__ = ["DIRECT_LDLT", "DIRECT_LU", "METHODS", "OUT_OF_CORE", "Compaction", "ContactProblem", "Mould",
           "PlateParameters",
           "Solution", "SolverError", "SolverOptions", "check_converged", "solve", "solve_problem"]

log = logging.getLogger(__name__)


def solve_problem(problem: ContactProblem, start: Solution | None = None, keep: bool = False) -> Solution:
    """Run the problem's contact iteration and free its PETSc objects (unless `keep`: for a solve
    of the problem renewed, ContactProblem.renew); the displacements, gaps and contact states as
    Functions per yarn. `start`: an earlier solution of a problem with the same unknowns (the same
    mid-surfaces), whose unknowns the exact method starts from."""
    t0 = time.perf_counter()
    try:
        x0 = None if start is None else start.unknowns
        out = solve_exact(problem, x0) if problem.exact else solve_penalty(problem)
        pen, volume = problem.penetration(out.gaps)
        gap, contact = problem.fields(out.gaps, out.active)
        unknowns = (out.x.getArray().copy(), out.forces)
        dt = problem.thickness_changes(out.x)
        pressure = None if out.forces is None else problem.platen_pressure(np.asarray(out.forces))
        w = problem.displacements(out.x)
        out.x.destroy()
        factorisations = problem.factorisations
    finally:
        if not keep:
            problem.destroy()
            release_freed_memory()  # MUMPS' factors back to the system before the outputs are made
    log.info("contact: %s (%d Newton steps, %d factorisations)", out.reason, out.iterations, factorisations)
    return Solution(w=w, gap=gap, contact=contact, iterations=out.iterations, updates=out.updates,
                    history=out.history, max_penetration=pen, penetration_volume=volume, converged=out.converged,
                    reason=out.reason, times={"solve": time.perf_counter() - t0}, unknowns=unknowns, dt=dt,
                    pressure=pressure)


def solve(ms: MidSurfaces, params: PlateParameters = PlateParameters(), options: SolverOptions = SolverOptions(),
          **kwargs) -> Solution:
    """Assemble and solve the textile's plates with contact (kwargs: loads, foundation_stiffness)."""
    t = time.perf_counter()
    problem = ContactProblem(ms, params, options, **kwargs)
    assembled = time.perf_counter() - t
    solution = solve_problem(problem)
    solution.times["assemble"] = assembled
    return solution
