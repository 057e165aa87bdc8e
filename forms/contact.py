"""Contact between vertically adjacent yarns (DESIGN.md section 5).

With the upper yarn u and the lower yarn l over their overlap, the gap is
    g = (z_u - t_u/2) - (z_l + t_l/2)
and the energy 1/2 k(g) g^2 with k = Ec where g < 0 (penetration) and Et where g >= 0, integrated
over the overlap area. Both branches vanish with zero slope at g = 0, so the energy is C1 and its
Newton iteration at fixed k is an active-set method.

The forms are written on the upper yarn's mid-surface; the lower yarn's values at the same points
enter through the (exact) dof correspondence of the shared projected mesh.
"""

import ufl


def stiffness(g, Ec, Et, shift=0):
    """k(g): Ec where g < shift (penetration; shift = lambda/Ec for augmented Lagrangian), else Et."""
    return ufl.conditional(ufl.lt(g - shift, 0), Ec, Et)


def contact_mass(u, v, g, Ec, Et, dx, shift=0):
    """Bilinear k(g) u v on the overlap: the contact stiffness acting on the gap's variation."""
    return stiffness(g, Ec, Et, shift) * u * v * dx


def contact_pressure(v, g, Ec, Et, lam, dx):
    """Linear form of the augmented-Lagrangian pressure lam [N/mm^2] where contact is active."""
    return ufl.conditional(ufl.lt(g - lam / Ec, 0), lam, 0) * v * dx


def contact_energy(g, Ec, Et, lam, dx):
    """The contact energy whose Newton (active-set) steps the two forms above give: with the
    pressure lam (0 for the plain penalty), 1/2 Ec g^2 - lam g where g < lam / Ec, and the apart
    branch 1/2 Et g^2 shifted to meet it there (convex, C1 up to Et)."""
    at = lam / Ec
    penetrating = 0.5 * Ec * g**2 - lam * g
    apart = 0.5 * Et * (g**2 - at**2) - 0.5 * lam * at
    return ufl.conditional(ufl.lt(g - at, 0), penetrating, apart) * dx
