"""Linear elasticity of the periodic cell problem (DESIGN.md section 12).

Voigt notation with engineering shear strains, in the order

    eps_v = (e11, e22, e33, g23, g13, g12),  g_ij = 2 e_ij,
    sig_v = (s11, s22, s33, s23, s13, s12),

so that sig_v = D eps_v and the energy density is psi = 1/2 eps_v . D eps_v, D the symmetric 6 x 6
stiffness [MPa] in global axes. D is a coefficient (a DG0 field: one matrix per cell), which covers
every material symmetry at once: the caller rotates each cell's material into global axes (Bond's
matrix; for a yarn, transversely isotropic about its fibre direction a).

Cell problem (Suquet 1987; Michel, Moulinec & Suquet 1999): for a mean strain E (a constant), find
the periodic fluctuation v with

    int_Y eps_v(w) . D (E + eps_v(v)) dx = 0   for every periodic w,

i.e. a(v, w) = L(w) with a(v, w) = int eps_v(w) . D eps_v(v) dx and L(w) = -int eps_v(w) . D E dx.
The effective stiffness is the energy of the total strains, C_ij = 1/|Y| int (E_i + eps_v(v_i)) . D
(E_j + eps_v(v_j)) dx, symmetric by construction.
"""

from __future__ import annotations

import ufl
from ufl import Form, Measure
from ufl.core.expr import Expr

__all__ = ["elastic_cell_forms", "elastic_energy_density", "strain", "voigt_strain", "voigt_stress"]


def strain(u: Expr) -> Expr:
    """Small strain tensor eps(u) = sym grad u."""
    return ufl.sym(ufl.grad(u))


def voigt_strain(eps: Expr) -> Expr:
    """Engineering Voigt vector (e11, e22, e33, 2 e23, 2 e13, 2 e12) of a 3 x 3 strain tensor."""
    return ufl.as_vector([eps[0, 0], eps[1, 1], eps[2, 2], 2 * eps[1, 2], 2 * eps[0, 2], 2 * eps[0, 1]])


def voigt_stress(D: Expr, eps_v: Expr) -> Expr:
    """Voigt stress sig_v = D eps_v [MPa] (eps_v in the order of `voigt_strain`)."""
    return ufl.dot(D, eps_v)


def elastic_energy_density(D: Expr, eps_v: Expr) -> Expr:
    """psi = 1/2 eps_v . D eps_v [MPa = mJ/mm^3]."""
    return 0.5 * ufl.dot(eps_v, voigt_stress(D, eps_v))


def elastic_cell_forms(v: Expr, w: Expr, D: Expr, E: Expr, dx: Measure) -> tuple[Form, Form]:
    """(a, L) of the cell problem: a = int eps_v(w) . D eps_v(v), L = -int eps_v(w) . D E.

    v, w: trial and test functions of the fluctuation (vector Lagrange); D: 6 x 6 stiffness
    coefficient [MPa]; E: the mean strain, a 6-vector in Voigt order (engineering shear).
    """
    ew = voigt_strain(strain(w))
    return (ufl.dot(ew, voigt_stress(D, voigt_strain(strain(v)))) * dx,
            -ufl.dot(ew, voigt_stress(D, E)) * dx)
