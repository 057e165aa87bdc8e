"""The thermal cell problem: three load cases (unit mean temperature gradients) -> effective
conductivity K (3 x 3).

The fluctuation lives in scalar Lagrange elements of the same degree as the elastic one; GAMG's
default near-null space (the constant) is the right one.
"""

from __future__ import annotations

import basix.ufl
import numpy as np
import ufl

import dolfinx
from textile_fenicsx.homogenisation.cellproblem import CellProblem, cell_measure, two_level
from textile_fenicsx.homogenisation.conduction_forms import conduction_cell_forms
from textile_fenicsx.homogenisation.periodic import Box

__all__ = ["ThermalCellProblem"]


class ThermalCellProblem(CellProblem):
    """The periodic thermal cell of a DG0 conductivity field K (3 x 3 per cell, W/(m K), global axes).

    `fluctuation_energies()` solves the three load cases; the effective conductivity is then
    (int K dx + energies) / |Y|.
    """

    def __init__(self, K: dolfinx.fem.Function, box: Box, options: dict | None, degree: int = 2):
        mesh = K.function_space.mesh
        V = dolfinx.fem.functionspace(mesh, basix.ufl.element("Lagrange", mesh.basix_cell(), degree))
        G = dolfinx.fem.Constant(mesh, np.zeros(3, dtype=dolfinx.default_scalar_type))
        a, L = conduction_cell_forms(ufl.TrialFunction(V), ufl.TestFunction(V), K, G, cell_measure(mesh, degree))
        coarse = ThermalCellProblem(K, box, None, 1) if degree > 1 and two_level(options) else None
        super().__init__(V, a, L, G, box, options, "conduction", coarse=coarse)

    def fluctuation_energies(self) -> dict:
        """Solve the three unit mean gradients; see CellProblem.solve."""
        return self.solve(np.eye(3))
