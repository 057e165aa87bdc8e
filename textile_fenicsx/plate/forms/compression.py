"""Transverse compression of a yarn: the fibre bundle's compaction law (DESIGN.md section 5).

A yarn's plate has a thickness t over each point of its footprint. Its fibres stay where they are
in the plane (the width is kept), so the intra-yarn fibre fraction goes as phi = phi0 t0 / t, t0 the
relaxed thickness and phi0 the relaxed fraction. Van Wyk's law gives the pressure that holds the
bundle at phi,
    p(t) = k E_f (phi^3 - phi0^3) = k E_f phi0^3 ((t0 / t)^3 - 1)            [N/mm^2],
and the energy per unit area stored in compressing it from t0 to t is the work of that pressure,
    W(t) = int_t^t0 p(s) ds = k E_f phi0^3 (t0^3 / 2 (1 / t^2 - 1 / t0^2) - (t0 - t))   [N/mm].
W is convex for t > 0 (W'' = 3 k E_f phi0^3 t0^3 / t^4) and least at t0; the maximum packing
(t >= phi0 t0 / phi_max) is a linear constraint of the solver, not a term of the energy.

The integral is taken at the P2 nodes (NODAL: row-sum-free "diagonal scaling" lumping, the
consistent mass matrix's diagonal scaled to the cell's area: 1/19 of it at each vertex, 16/57 at
each edge midpoint). Each node then holds its own share of the bundle, W(t_i) times its area, and a
platen pressing a uniform yarn meets every node with a force, the vertices too: with the
consistent integral the vertices of P2 carry none, their constraints are degenerate (active at
zero force), and the interior point crawled (a flat yarn in a mould: 100 steps, not converged).
The rule integrates linear fields exactly: the energy converges at second order in the seed.
"""

import ufl
from ufl import Form, Measure
from ufl.core.expr import Expr

# the P2 nodes of the reference triangle (basix's order: vertices, then the edges' midpoints) and
# their lumped weights (sum 1/2, the reference area)
NODAL = {"quadrature_rule": "custom",
         "quadrature_points": ((0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (0.5, 0.5), (0.0, 0.5), (0.5, 0.0)),
         "quadrature_weights": (1 / 38,) * 3 + (8 / 57,) * 3}


def compaction_pressure(t: Expr, t0: Expr, modulus: Expr | float, phi0: Expr | float) -> Expr:
    """Van Wyk's p(t) = k E_f phi0^3 ((t0 / t)^3 - 1) [N/mm^2]; modulus = k E_f [N/mm^2]."""
    return modulus * phi0**3 * ((t0 / t) ** 3 - 1)


def compaction_energy(t: Expr, t0: Expr, modulus: Expr | float, phi0: Expr | float, dx: Measure) -> Form:
    """The energy of the bundle compressed from t0 to t, W(t) integrated over dx [N mm]."""
    W = modulus * phi0**3 * (t0**3 / 2 * (1 / t**2 - 1 / t0**2) - (t0 - t))
    return W * dx(metadata=NODAL)


def compaction_forms(dt: Expr, t0: Expr, modulus: Expr | float, phi0: Expr | float,
                     dx: Measure) -> tuple[Form, Form, Form]:
    """(energy, residual, Jacobian) of the compaction energy at t = t0 + dt with respect to the
    thickness change dt (a Function on the yarn's space)."""
    energy = compaction_energy(t0 + dt, t0, modulus, phi0, dx)
    V = dt.function_space
    residual = ufl.derivative(energy, dt, ufl.TestFunction(V))
    return energy, residual, ufl.derivative(residual, dt, ufl.TrialFunction(V))
