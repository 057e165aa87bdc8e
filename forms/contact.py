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
The forms live on the upper yarn's mid-surface; the lower yarn's values at the same points enter
through the (exact) dof correspondence of the shared projected mesh.
"""

import ufl
from ufl import Form, Measure
from ufl.core.expr import Expr

# g is P2, the energy's density of degree 4 (the conditional does not raise it)
QUADRATURE = {"quadrature_degree": 4}


def stiffness(g: Expr, Ec: Expr | float, Et: Expr | float) -> Expr:
    """k(g): Ec where g < 0 (penetration), else Et [N/mm^3]."""
    return ufl.conditional(ufl.lt(g, 0), Ec, Et)


def contact_energy(g: Expr, Ec: Expr | float, Et: Expr | float, dx: Measure, exact: bool = False) -> Form:
    """Contact energy over the overlap dx [N mm]: 1/2 k(g) g^2 (penalty) or 1/2 Et g^2 (exact)."""
    k = Et if exact else stiffness(g, Ec, Et)
    return 0.5 * k * g**2 * dx(metadata=QUADRATURE)


def contact_forms(g: Expr, Ec: Expr | float, Et: Expr | float, dx: Measure,
                  exact: bool = False) -> tuple[Form, Form, Form]:
    """(energy, residual, Jacobian) of the contact energy with respect to the gap Function g."""
    energy = contact_energy(g, Ec, Et, dx, exact)
    V = g.function_space
    residual = ufl.derivative(energy, g, ufl.TestFunction(V))
    return energy, residual, ufl.derivative(residual, g, ufl.TrialFunction(V))


def penetration_volume(g: Expr, dx: Measure) -> Form:
    """The volume of interpenetration the gap field says: the integral of max(0, -g) [mm^3]."""
    return ufl.max_value(-g, 0) * dx(metadata=QUADRATURE)
