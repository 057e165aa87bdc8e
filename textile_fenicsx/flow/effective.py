"""The cell's permeability tensor: three flow cell problems (a unit mean pressure gradient along x,
y and z) on a volume mesh with its fields, K_ij = mu <u_i> for the gradient along j.

    result = permeability(fields, PermeabilityOptions(yarns="gebart", fibre_radius=0.0035))
    result.K          # (3, 3) [mm^2];  result.K_m2 [m^2]
    result.write(folder, comm)         # folder/permeability.json, flow.xdmf (+.h5), flow.vtu, flow.png

The yarns are Brinkman media whose tensor follows Gebart's laws at each element's fibre fraction and
fibre direction (gebart.py), an isotropic permeability given in m^2, or solid (impermeable: no-slip
on their surfaces). The flow is slow (Stokes) and the cell periodic in z too: a stack of plies in
phase.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from mpi4py import MPI

import dolfinx
from textile_fenicsx.common.errors import TextileError
from textile_fenicsx.common.files import atomic_path, staged_folder
from textile_fenicsx.flow import gebart
from textile_fenicsx.flow.problem import DIRECT, ITERATIVE, FlowCellProblem
from textile_fenicsx.homogenisation.periodic import Box, bounding_box
from textile_fenicsx.volume.files import VolumeFields
from textile_fenicsx.volume.refinement import error_summary

__all__ = ["DEFAULT_FIBRE_RADIUS", "Permeability", "PermeabilityOptions", "permeability", "yarn_permeability"]

log = logging.getLogger(__name__)

# a fibre radius [mm] where the model states none: 3.5 um, carbon's (T300: 7 um across); E-glass
# fibres are 5-12 um in radius. Gebart's K scales with r^2: a run that uses it says so.
DEFAULT_FIBRE_RADIUS = 0.0035
MM2_TO_M2 = 1e-6
SOLVERS = {"auto": None, "direct": DIRECT, "iterative": ITERATIVE}


@dataclass(frozen=True)
class PermeabilityOptions:
    """yarns: "gebart" (Gebart's laws at each element's fibre fraction and direction), "impermeable"
    (solid yarns, no-slip on their surfaces) or a permeability [m^2] (isotropic, every yarn);
    fibre_radius [mm] for Gebart (None: DEFAULT_FIBRE_RADIUS, with a warning); degree: the
    velocity's (the pressure's is one less; Taylor-Hood); mu: the fluid's viscosity [Pa s] (K does
    not depend on it); box: the periodic cell (None: the mesh's bounding box); memory_limit [GB]:
    refuse a mesh whose solve would need more (None: the memory available); solver: "direct" (MUMPS'
    LU), "iterative" (FGMRES, block preconditioner: problem.ITERATIVE) or "auto" (direct for small
    cells where it fits, problem.choose_solver)."""

    yarns: str | float = "gebart"
    fibre_radius: float | None = None
    degree: int = 2
    mu: float = 1.0
    box: Box | None = None
    memory_limit: float | None = None
    solver: str = "auto"

    def __post_init__(self):
        if isinstance(self.yarns, str):
            if self.yarns not in ("gebart", "impermeable"):
                raise TextileError(f"yarn permeability must be gebart, impermeable or a value in m^2, not "
                                   f"{self.yarns!r}")
        elif not (isinstance(self.yarns, (int, float)) and np.isfinite(self.yarns) and self.yarns > 0):
            raise TextileError(f"yarn permeability must be a positive number of m^2, not {self.yarns!r}")
        if self.fibre_radius is not None and not (np.isfinite(self.fibre_radius) and 0 < self.fibre_radius < 1.0):
            raise TextileError(f"fibre radius must be a positive length under 1 mm, not {self.fibre_radius!r}")
        if self.solver not in SOLVERS:
            raise TextileError(f"the flow solver must be one of {', '.join(SOLVERS)}, not {self.solver!r}")
        if self.degree != 2:
            raise TextileError(f"the flow problem is Taylor-Hood of degree 2 (velocity) and 1 (pressure), not "
                               f"{self.degree!r}")


@dataclass
class Permeability:
    """K (3 x 3) [mm^2]; principal values [mm^2] and directions (columns); vf: the cell's fibre
    volume fraction; porosity: the pores' volume fraction; dofs, seconds, options, checks;
    velocities: the three load cases' solutions (mixed velocity-pressure Functions), mu: the
    viscosity they were solved with [Pa s]."""

    K: np.ndarray
    vf: float
    porosity: float
    dofs: int
    seconds: dict
    options: dict
    velocities: list = field(default_factory=list, repr=False)
    mu: float = 1.0
    error: dict | None = None  # the discretisation error's estimate (volume/refinement.py), where made

    @property
    def K_m2(self) -> np.ndarray:
        return self.K * MM2_TO_M2

    @property
    def principal(self) -> tuple[np.ndarray, np.ndarray]:
        values, vectors = np.linalg.eigh(0.5 * (self.K + self.K.T))
        return values[::-1], vectors[:, ::-1]

    @property
    def checks(self) -> dict:
        """asymmetry: max |K - K^T| / max |K|; positive_definite: K restricted to the axes the pores
        percolate along (options["percolates"]; K is 0 along the others)."""
        scale = float(np.abs(self.K).max()) or 1.0
        flags = self.options.get("percolates", {})
        axes = [i for i, axis in enumerate("xyz") if flags.get(axis, True)]
        open_block = 0.5 * (self.K + self.K.T)[np.ix_(axes, axes)]
        return {"asymmetry": float(np.abs(self.K - self.K.T).max() / scale),
                "positive_definite": bool(np.all(np.linalg.eigvalsh(open_block) > 0)) if len(open_block) else False}

    def summary(self) -> str:
        values = self.principal[0] * MM2_TO_M2
        iterations = self.options.get("iterations") or []
        solve = f", {'/'.join(map(str, iterations))} iterations" if any(n > 1 for n in iterations) else ""
        return (f"Kxx {self.K_m2[0, 0]:.4g} Kyy {self.K_m2[1, 1]:.4g} Kzz {self.K_m2[2, 2]:.4g} m^2 "
                f"(principal {values[0]:.4g}, {values[1]:.4g}, {values[2]:.4g}), Vf {self.vf:.3f}, "
                f"porosity {self.porosity:.3f}; {self.dofs} dofs{solve}, {self.seconds['total']:.1f} s"
                + error_summary(self.error))

    def document(self) -> dict:
        values, vectors = self.principal
        return {"K_m2": self.K_m2.tolist(), "K_mm2": self.K.tolist(),
                "principal_m2": (values * MM2_TO_M2).tolist(), "principal_directions": vectors.T.tolist(),
                "vf": self.vf, "porosity": self.porosity, "dofs": self.dofs, "seconds": self.seconds,
                "checks": self.checks, "options": self.options, "error_estimate": self.error,
                "definition": "K_ij = mu <u_i> for a unit mean pressure gradient along -j (Darcy: <u> = -K/mu grad P); "
                              "periodic in x, y and z; Stokes in the pores, Brinkman in the yarns with the "
                              "fluid's viscosity"}

    def write(self, folder: str | Path, comm: MPI.Comm = MPI.COMM_WORLD) -> Path:
        """folder/permeability.json and, with the velocities, the flow's files (flow/files.py:
        flow.xdmf + .h5, flow.vtu, flow.png); they appear together once all are written, or none
        does (staged_folder; other files in the folder are kept; the folder created if missing;
        collective over comm, the velocities' communicator). Returns the path of permeability.json."""
        from textile_fenicsx.flow.files import FILES, write_flow

        folder = Path(folder)
        with staged_folder(folder, comm, remove=FILES) as tmp:
            if comm.rank == 0:
                with atomic_path(tmp / "permeability.json") as path:
                    path.write_text(json.dumps(self.document(), indent=1))
            if self.velocities:
                write_flow(self.velocities, tmp, self.mu, self.K)
        comm.barrier()  # rank 0 has moved them into the folder: every rank may read them
        return folder / "permeability.json"


def yarn_permeability(fields: VolumeFields, options: PermeabilityOptions) -> tuple[np.ndarray, np.ndarray]:
    """Each local cell's permeability tensor (n, 3, 3) [mm^2] (0 in the pores and in solid yarns)
    and whether it is a yarn cell (n,)."""
    mesh = fields.mesh
    n = mesh.topology.index_map(3).size_local + mesh.topology.index_map(3).num_ghosts
    yarn = np.zeros(n, bool)
    yarn[fields.phase.indices] = fields.phase.values > 0
    if mesh.comm.size > 1:  # the tags hold the owned cells: the ghosts' from their owners
        tag = dolfinx.fem.Function(fields.yarn_vf.function_space)
        tag.x.array[fields.yarn_vf.function_space.dofmap.list[:, 0]] = yarn.astype(float)
        tag.x.scatter_forward()
        yarn = tag.x.array[fields.yarn_vf.function_space.dofmap.list[:, 0]] > 0.5
    K = np.zeros((n, 3, 3))
    if options.yarns == "impermeable":
        return K, yarn
    if not isinstance(options.yarns, str):
        K[yarn] = np.eye(3) * float(options.yarns) / MM2_TO_M2
        return K, yarn
    vf = fields.yarn_vf.x.array[fields.yarn_vf.function_space.dofmap.list[:, 0]][yarn]
    if np.any(vf >= gebart.VMAX) or np.any(vf <= 0):
        raise TextileError(f"a yarn's fibre volume fraction {float(vf.max() if len(vf) else 0):.4f} is outside "
                           f"(0, {gebart.VMAX:.4f}), where Gebart's transverse law holds")
    d = fields.direction.x.array.reshape(-1, 3)[fields.direction.function_space.dofmap.list[:, 0]][yarn]
    radius = options.fibre_radius or DEFAULT_FIBRE_RADIUS
    K[yarn] = gebart.tensors(d, gebart.axial(vf, radius), gebart.transverse(vf, radius))
    return K, yarn


def permeability(fields: VolumeFields, options: PermeabilityOptions | None = None) -> Permeability:
    """The cell's permeability (module docstring; collective)."""
    options = options or PermeabilityOptions()
    mesh = fields.mesh
    comm = mesh.comm
    t0 = time.perf_counter()
    if options.yarns == "gebart" and options.fibre_radius is None and comm.rank == 0:
        log.warning("no fibre radius given: Gebart's yarn permeability takes %g mm (--fibre-radius sets it; "
                    "K_yarn scales with its square)", DEFAULT_FIBRE_RADIUS)
    box = options.box or bounding_box(mesh)
    K_yarn, yarn = yarn_permeability(fields, options)
    T = dolfinx.fem.functionspace(mesh, ("DG", 0, (3, 3)))
    K_inv = dolfinx.fem.Function(T, name="inverse_permeability")
    inverse = np.zeros_like(K_yarn)
    porous = yarn if options.yarns != "impermeable" else np.zeros_like(yarn)
    inverse[porous] = np.linalg.inv(K_yarn[porous])
    K_inv.x.array.reshape(-1, 9)[T.dofmap.list[:, 0]] = inverse.reshape(-1, 9)
    solid = yarn if options.yarns == "impermeable" else None
    volumes = _cell_volumes(mesh)
    owned = mesh.topology.index_map(3).size_local
    vf_local = fields.yarn_vf.x.array[fields.yarn_vf.function_space.dofmap.list[:owned, 0]]
    vf = comm.allreduce(float(np.dot(vf_local, volumes[:owned])), op=MPI.SUM) / box.volume
    porosity = 1.0 - comm.allreduce(float(volumes[:owned][yarn[:owned]].sum()), op=MPI.SUM) / box.volume
    seconds: dict = {"fields": time.perf_counter() - t0}
    problem = FlowCellProblem(K_inv, box, options.degree, options.mu, solid, SOLVERS[options.solver],
                              memory_limit=options.memory_limit)
    try:
        seconds["assembly"], seconds["solver_setup"] = problem.assembly_seconds, problem.setup_seconds
        t1 = time.perf_counter()
        flows = problem.solve(np.eye(3))
        K = options.mu * np.array([problem.mean_velocity(w) for w in flows]).T
        closed = ~problem.percolates
        if np.any(closed):  # no path across the cell: no flow along it, whatever the solve's round-off
            K[closed, :], K[:, closed] = 0.0, 0.0
            if comm.rank == 0:
                log.warning("the pores do not percolate along %s with impermeable yarns: K = 0 there",
                            ", ".join("xyz"[i] for i in np.flatnonzero(closed)))
        seconds["solves"] = time.perf_counter() - t1
        dofs = problem.dofs
        solver = problem.description
        iterations = problem.iterations
    finally:
        problem.destroy()
    seconds["total"] = time.perf_counter() - t0
    document = {"yarns": options.yarns if isinstance(options.yarns, str) else float(options.yarns),
                "fibre_radius_mm": options.fibre_radius or DEFAULT_FIBRE_RADIUS, "degree": options.degree,
                "elements": f"Taylor-Hood: {mesh.topology.cell_name()} P{options.degree}-P{options.degree - 1}",
                "solver": solver, "iterations": iterations,
                "percolates": {axis: bool(flag) for axis, flag in zip("xyz", problem.percolates)}}
    return Permeability(K, vf, porosity, dofs, seconds, document, flows, mu=options.mu)


def _cell_volumes(mesh: dolfinx.mesh.Mesh) -> np.ndarray:
    """Each local cell's volume [mm^3]."""
    import ufl

    W = dolfinx.fem.functionspace(mesh, ("DG", 0))
    v = dolfinx.fem.Function(W)
    dolfinx.fem.petsc.assemble_vector(v.x.petsc_vec, dolfinx.fem.form(ufl.TestFunction(W) * ufl.dx))
    v.x.scatter_forward()
    return v.x.array[W.dofmap.list[:, 0]]
