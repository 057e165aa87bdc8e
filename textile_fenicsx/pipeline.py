"""One way through the house: textile -> projected mesh -> mid-surfaces -> solve (DESIGN.md 2)."""

import time
from dataclasses import dataclass, field

import numpy as np
from mpi4py import MPI

from textile_fenicsx.meshes.midsurface import MidSurfaces, mid_surfaces
from textile_fenicsx.meshes.projected import MeshOptions, projected_mesh, release_freed_memory
from textile_fenicsx.solver import ContactProblem, PlateParameters, Solution, SolverOptions
from textile_fenicsx.textile import Textile


@dataclass
class Run:
    """Everything one run produced, with the time each stage took [s]."""

    textile: Textile
    midsurfaces: MidSurfaces
    solution: Solution
    times: dict = field(default_factory=dict)
    problem: ContactProblem | None = None

    def summary(self) -> dict:
        """JSON-ready numbers of the run (collective)."""
        comm = self.midsurfaces.V.mesh.comm
        local = max([float(np.max(np.abs(w.x.array))) for w in self.solution.w if len(w.x.array)] or [0.0])
        sol = self.solution
        return {
            "dofs": int(sum(y.V.dofmap.index_map.size_global for y in self.midsurfaces.yarns)),
            "cells": int(self.midsurfaces.projected.stats["cells"]),
            "iterations": sol.iterations, "updates": sol.updates, "converged": sol.converged,
            "max_penetration_nodal": sol.max_penetration,
            "max_abs_w": comm.allreduce(local, op=MPI.MAX),
            "time_s": dict(self.times),
        }


def run(textile: Textile, mesh: MeshOptions = MeshOptions(), params: PlateParameters = PlateParameters(),
        options: SolverOptions = SolverOptions(), comm: MPI.Comm = MPI.COMM_WORLD, log=print) -> Run:
    """Mesh the textile's projected regions, sample its mid-surfaces and solve for the displacements."""
    say = log if (log is not None and comm.rank == 0) else (lambda *_: None)
    times = {}
    start = time.perf_counter()
    t = time.perf_counter()
    projected = projected_mesh(textile, mesh, comm, log=say)
    times["mesh"] = time.perf_counter() - t
    t = time.perf_counter()
    ms = mid_surfaces(projected, log=say)
    release_freed_memory()
    times["midsurfaces"] = time.perf_counter() - t
    t = time.perf_counter()
    problem = ContactProblem(ms, params, options, log=say)
    release_freed_memory()
    times["assemble"] = time.perf_counter() - t
    t = time.perf_counter()
    solution = problem.solve()
    times["solve"] = time.perf_counter() - t
    times["total"] = time.perf_counter() - start
    result = Run(textile, ms, solution, times, problem)
    s = result.summary()
    say(f"solve: {s['dofs']} dofs, {s['iterations']} iterations, max penetration "
        f"{s['max_penetration_nodal']:.3e} mm, max |w| {s['max_abs_w']:.4f} mm, "
        + ", ".join(f"{k} {v:.2f} s" for k, v in times.items()))
    if not solution.converged:
        say("solve: WARNING the contact iteration did not converge (see the iteration log)")
    return result
