"""Stokes-Brinkman flow of the periodic cell, in UFL (one domain: Stokes in the pores, Brinkman in
the yarns).

For a mean pressure gradient -f (a body force f [Pa/mm]), find the periodic velocity u [mm/s] and
pressure fluctuation p [Pa] with

    int mu grad u : grad v + int mu K^-1 u . v - int p div v - int q div u = int f . v

for every periodic (v, q). mu is the fluid's viscosity [Pa s]; the Brinkman term's effective
viscosity is mu too. K^-1 [mm^-2] is 0 in the pores and the inverse of the yarn's permeability
tensor in the yarns (a DG0 field). The cell's permeability is then K_ij = mu <u_i> / f_j over the
whole cell (Darcy: <u> = -K / mu grad P).
"""

from __future__ import annotations

import ufl
from ufl import Form, Measure
from ufl.core.expr import Expr

__all__ = ["brinkman_drag", "stokes_brinkman_forms", "viscous"]


def viscous(mu: Expr, u: Expr, v: Expr) -> Expr:
    """mu grad u : grad v: the viscous term (with a periodic u, the same as 2 mu eps(u) : eps(v)
    for a divergence-free u)."""
    return mu * ufl.inner(ufl.grad(u), ufl.grad(v))


def brinkman_drag(mu: Expr, K_inv: Expr, u: Expr, v: Expr) -> Expr:
    """mu K^-1 u . v: the drag of the fibres in a yarn (0 in the pores)."""
    return mu * ufl.inner(ufl.dot(K_inv, u), v)


def stokes_brinkman_forms(u: Expr, p: Expr, v: Expr, q: Expr, mu: Expr, K_inv: Expr, f: Expr,
                          dx: Measure) -> tuple[Form, Form]:
    """(a, L) of the cell's flow problem (module docstring); u, p trial and v, q test functions of
    the mixed velocity-pressure space."""
    a = (viscous(mu, u, v) + brinkman_drag(mu, K_inv, u, v) - p * ufl.div(v) - q * ufl.div(u)) * dx
    return a, ufl.inner(f, v) * dx
