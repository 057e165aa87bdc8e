"""Steady heat conduction of the periodic cell problem (DESIGN.md section 12).

Fourier's law q = -K grad T, K the symmetric conductivity tensor [W/(m K)] as a coefficient (a DG0
field: one tensor per cell). A yarn conducts as a transversely isotropic body about its fibre
direction a,

    K = kT I + (kL - kT) a (x) a,

kL along the fibres, kT across; the caller builds K per cell (isotropic matrix: kL = kT = k).

Cell problem: for a mean temperature gradient G (a constant vector), find the periodic fluctuation t
with int_Y grad w . K (G + grad t) dx = 0 for every periodic w; the effective conductivity is the
energy K_ij = 1/|Y| int (e_i + grad t_i) . K (e_j + grad t_j) dx, so that the mean flux is
<q> = -K_eff G, and K_eff is symmetric by construction.
"""

from __future__ import annotations

import ufl
from ufl import Form, Measure
from ufl.core.expr import Expr

__all__ = ["conduction_cell_forms", "heat_flux"]


def heat_flux(K: Expr, grad_T: Expr) -> Expr:
    """q = -K grad T [W/m^2 for K in W/(m K) and grad T in K/m]."""
    return -ufl.dot(K, grad_T)


def conduction_cell_forms(t: Expr, w: Expr, K: Expr, G: Expr, dx: Measure) -> tuple[Form, Form]:
    """(a, L) of the cell problem: a = int grad w . K grad t, L = -int grad w . K G.

    t, w: trial and test functions of the temperature fluctuation (scalar Lagrange); K: 3 x 3
    conductivity coefficient; G: the mean temperature gradient, a 3-vector.
    """
    return (-ufl.dot(ufl.grad(w), heat_flux(K, ufl.grad(t))) * dx,
            ufl.dot(ufl.grad(w), heat_flux(K, G)) * dx)
