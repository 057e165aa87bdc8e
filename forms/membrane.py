"""Tension along the fibre (geometric stiffness), and the soft foundation and load used in checks.

Tension energy density (DESIGN.md section 5): 1/2 sigma1 (d . grad z)^2, sigma1 [N/mm] the fibre
tension per unit width, d the in-plane fibre direction.
"""

import ufl


def tension(u, v, d, sigma1, dx):
    """Bilinear form of fibre tension: sigma1 (d . grad u)(d . grad v)."""
    d = d / ufl.sqrt(ufl.dot(d, d))
    return sigma1 * ufl.dot(d, ufl.grad(u)) * ufl.dot(d, ufl.grad(v)) * dx


def foundation(u, v, k, dx):
    """Bilinear form of an elastic foundation of stiffness k [N/mm^3]: k u v."""
    return k * u * v * dx


def load(v, q, dx):
    """Linear form of a transverse load q [N/mm^2] (positive up)."""
    return q * v * dx
