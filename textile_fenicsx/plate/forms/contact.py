"""Contact between vertically adjacent yarns (DESIGN.md section 5).

With the upper yarn u and the lower yarn l over their overlap, the gap is
    g = (z_u - t_u/2) - (z_l + t_l/2)
and the contact energy is written once, as a function of g; its residual and Jacobian are its
derivatives (`ufl.derivative` with respect to the gap Function):
- penalty (the paper's): 1/2 k(g) g^2, k = Ec where g < 0 (penetration) and Et where g >= 0. Both
  branches vanish with zero slope at g = 0, so the energy is convex and C1 and Newton on it is an
  active-set method;
- exact: 1/2 Et g^2 only (the spring that holds yarns together where they are apart); penetration
  is excluded by the constraint g >= 0 at the nodes, which the solver imposes itself.
  Lumped (where the yarns flatten, DESIGN.md 5a): the spring's integral taken by the P2 nodes' rule
  (NODAL_P2), so its Jacobian is diagonal and couples no thickness change to its neighbours'.
The forms live on the upper yarn's mid-surface; the lower yarn's values at the same points enter
through the (exact) dof correspondence of the shared projected mesh.
"""

import numpy as np
import ufl
from ufl import Form, Measure
from ufl.core.expr import Expr

# g is P2, the energy's density of degree 4 (the conditional does not raise it)
QUADRATURE = {"quadrature_degree": 4}
# a rule on the P2 triangle's nodes (vertices 1/19, edge midpoints 16/57 of the area): row-sum
# lumping cannot serve P2 (its vertex functions integrate to 0), HRZ lumping can (the consistent
# matrix's diagonal, 1/30 and 8/45 of the area, scaled to the total), and on straight-sided
# triangles with a constant stiffness HRZ is this rule. It integrates degree 1 exactly
NODAL_P2 = {"quadrature_rule": "custom",
            "quadrature_points": np.array([[0, 0], [1, 0], [0, 1], [0.5, 0.5], [0, 0.5], [0.5, 0]], float),
            "quadrature_weights": np.array([1 / 19] * 3 + [16 / 57] * 3) / 2}


def stiffness(g: Expr, Ec: Expr | float, Et: Expr | float) -> Expr:
    """k(g): Ec where g < 0 (penetration), else Et [N/mm^3]."""
    return ufl.conditional(ufl.lt(g, 0), Ec, Et)


def contact_energy(g: Expr, Ec: Expr | float, Et: Expr | float, dx: Measure, exact: bool = False,
                   lumped: bool = False) -> Form:
    """Contact energy over the overlap dx [N mm]: 1/2 k(g) g^2 (penalty) or 1/2 Et g^2 (exact;
    lumped: by the nodes' rule NODAL_P2)."""
    if lumped and not exact:
        raise ValueError("only the exact method's spring is lumped (the penalty's k(g) switches between nodes)")
    k = Et if exact else stiffness(g, Ec, Et)
    return 0.5 * k * g**2 * dx(metadata=NODAL_P2 if lumped else QUADRATURE)


def contact_forms(g: Expr, Ec: Expr | float, Et: Expr | float, dx: Measure,
                  exact: bool = False, lumped: bool = False) -> tuple[Form, Form, Form]:
    """(energy, residual, Jacobian) of the contact energy with respect to the gap Function g."""
    energy = contact_energy(g, Ec, Et, dx, exact, lumped)
    V = g.function_space
    residual = ufl.derivative(energy, g, ufl.TestFunction(V))
    return energy, residual, ufl.derivative(residual, g, ufl.TrialFunction(V))


def penetration_volume(g: Expr, dx: Measure) -> Form:
    """The volume of interpenetration the gap field says: the integral of max(0, -g) [mm^3]."""
    return ufl.max_value(-g, 0) * dx(metadata=QUADRATURE)
