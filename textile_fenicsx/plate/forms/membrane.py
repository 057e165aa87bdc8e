"""Tension along the fibre (geometric stiffness), and the soft foundation and load used in checks.

Tension energy density (DESIGN.md section 5): 1/2 sigma1 (d . grad z)^2, sigma1 [N/mm] the fibre
tension per unit width, d the in-plane fibre direction.
"""

import ufl
from ufl import Form, Measure
from ufl.core.expr import Expr


def tension(u: Expr, v: Expr, d: Expr, sigma1: Expr | float, dx: Measure) -> Form:
    """Bilinear form of fibre tension: sigma1 (d . grad u)(d . grad v)."""
    d = d / ufl.sqrt(ufl.dot(d, d))
    return sigma1 * ufl.dot(d, ufl.grad(u)) * ufl.dot(d, ufl.grad(v)) * dx


def foundation(u: Expr, v: Expr, k: Expr | float, dx: Measure) -> Form:
    """Bilinear form of an elastic foundation of stiffness k [N/mm^3]: k u v."""
    return k * u * v * dx


def load(v: Expr, q: Expr | float, dx: Measure) -> Form:
    """Linear form of a transverse load q [N/mm^2] (positive up)."""
    return q * v * dx
