"""The elastic cell problem: six load cases (unit mean strains) -> effective stiffness C (6 x 6).

Voigt order 11, 22, 33, 23, 13, 12 with engineering shear strains (constants.py); the load case k
is the mean strain E = e_k. The fluctuation lives in vector Lagrange elements of the mesh's cell
(P2 on tetrahedra, Q2 on hexahedra by default); GAMG gets the six rigid-body modes as its
near-null space (DOLFINx's elasticity demo), which the periodic constraint does not remove
locally.
"""

from __future__ import annotations

import basix.ufl
import numpy as np
import ufl

import dolfinx
from textile_fenicsx.homogenisation.cellproblem import CellProblem, cell_measure, two_level
from textile_fenicsx.homogenisation.elasticity_forms import elastic_cell_forms
from textile_fenicsx.homogenisation.periodic import Box

__all__ = ["ElasticCellProblem", "rigid_body_modes"]


def rigid_body_modes(V: dolfinx.fem.FunctionSpace) -> list[np.ndarray]:
    """Three translations and three rotations at V's owned dofs (blocked layout x0 y0 z0 x1 ...)."""
    x = V.tabulate_dof_coordinates()[: V.dofmap.index_map.size_local]
    modes = [np.zeros((len(x), 3)) for _ in range(6)]
    for i in range(3):
        modes[i][:, i] = 1.0
    for m, (i, j) in zip(modes[3:], ((0, 1), (1, 2), (2, 0))):  # rotations in the ij planes
        m[:, i], m[:, j] = -x[:, j], x[:, i]
    return [m.ravel() for m in modes]


class ElasticCellProblem(CellProblem):
    """The periodic elastic cell of a DG0 stiffness field D (6 x 6 per cell, MPa, global axes).

    `fluctuation_energies()` solves the six load cases; the effective stiffness is then
    (int D dx + energies) / |Y| (effective.py adds the first term from the cells).
    """

    def __init__(self, D: dolfinx.fem.Function, box: Box, options: dict | None, degree: int = 2):
        mesh = D.function_space.mesh
        V = dolfinx.fem.functionspace(mesh, basix.ufl.element("Lagrange", mesh.basix_cell(), degree, shape=(3,)))
        E = dolfinx.fem.Constant(mesh, np.zeros(6, dtype=dolfinx.default_scalar_type))
        a, L = elastic_cell_forms(ufl.TrialFunction(V), ufl.TestFunction(V), D, E, cell_measure(mesh, degree))
        coarse = ElasticCellProblem(D, box, None, 1) if degree > 1 and two_level(options) else None
        super().__init__(V, a, L, E, box, options, "elasticity", near_null=rigid_body_modes(V), coarse=coarse)

    def fluctuation_energies(self) -> dict:
        """Solve the six unit mean strains; see CellProblem.solve."""
        return self.solve(np.eye(6))
