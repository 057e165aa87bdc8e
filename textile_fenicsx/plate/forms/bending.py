"""Anisotropic Kirchhoff bending as a C0 interior-penalty (DG) form on continuous Lagrange elements.

Energy density (DESIGN.md section 5), in the yarn frame (d along the fibre, n = d rotated +90 deg):

    psi = 1/2 (Db1 k11^2 + Db2 k22^2 + 4 Db12 k12^2),   k11 = d.H.d, k22 = n.H.n, k12 = d.H.n,

with H = grad grad z. The moment is M = dpsi/dH = R diag-form(Db1 k11, 2 Db12 k12, Db2 k22) R^T,
R = [d | n]. Continuous P2 has no continuous slope, so the facet terms of the symmetric interior
penalty method restore it weakly (Brenner & Sung 2005; Engel et al. 2002):

    a(u, v) = sum_K (M(u) : H(v))_K
              - sum_F ({M_nn(u)}, [dv/dn])_F - sum_F ({M_nn(v)}, [du/dn])_F
              + sum_F (alpha D / h_F [du/dn], [dv/dn])_F

with [dv/dn] = grad v+ . n+ + grad v- . n- (the jump of the normal slope) and {.} the average.
The facet size h_F is the cells' areas over the facet's length, 1/h_F = {|F| / |K|}: the trace
inequality ||grad v . n||_F^2 <= C |F| / |K| ||grad v||_K^2 holds with this ratio on any triangle,
however thin, so the form stays coercive on sliver cells (with the cell diameter it did not: a
2-degree sliver has a diameter like its neighbours' but a tiny area, and the matrix became
indefinite).
"""

import ufl
from ufl import Form, Measure
from ufl.core.expr import Expr


def fibre_frame(d: Expr) -> tuple[Expr, Expr]:
    """Return (d, n): the unit fibre direction and its in-plane normal n = d rotated by +90 degrees.

    d: a 2D vector expression (need not be unit length: it is normalised here).
    """
    d = d / ufl.sqrt(ufl.dot(d, d))
    return d, ufl.as_vector((-d[1], d[0]))


def curvature(z: Expr, d: Expr) -> tuple[Expr, Expr, Expr]:
    """Curvatures (k11, k22, k12) of the height field z in the frame of fibre direction d."""
    d, n = fibre_frame(d)
    H = ufl.grad(ufl.grad(z))
    return ufl.dot(d, H * d), ufl.dot(n, H * n), ufl.dot(d, H * n)


def moment(z: Expr, d: Expr, Db1: Expr | float, Db2: Expr | float, Db12: Expr | float) -> Expr:
    """Bending moment tensor M = dpsi/dH (2x2, global axes) for stiffnesses Db1, Db2, Db12 [N mm]."""
    d, n = fibre_frame(d)
    k11, k22, k12 = curvature(z, d)
    return (
        Db1 * k11 * ufl.outer(d, d)
        + Db2 * k22 * ufl.outer(n, n)
        + 2 * Db12 * k12 * (ufl.outer(d, n) + ufl.outer(n, d))
    )


def c0ip_bending(u: Expr, v: Expr, d: Expr, Db1: Expr | float, Db2: Expr | float, Db12: Expr | float,
                 alpha: Expr | float, dx: Measure, dS: Measure) -> Form:
    """Bilinear form of anisotropic bending, C0 interior penalty, on the cells of dx and facets of dS.

    u, v: trial and test functions (or Functions) of a continuous Lagrange space of degree >= 2.
    d: fibre direction (may be discontinuous between cells). alpha: penalty factor (3 is enough with this h_F),
    scaled by max(Db1, Db2, Db12) / h_F on each facet (h_F: cell areas over facet length).
    """
    mesh = dx.ufl_domain()
    nF = ufl.FacetNormal(mesh)
    D = ufl.max_value(ufl.max_value(Db1, Db2), Db12)
    inv_h = ufl.avg(ufl.FacetArea(mesh) / ufl.CellVolume(mesh))

    def M_nn(w: Expr) -> Expr:  # average normal moment on a facet
        return ufl.dot(ufl.avg(moment(w, d, Db1, Db2, Db12)) * nF("+"), nF("+"))

    def slope_jump(w: Expr) -> Expr:
        return ufl.jump(ufl.grad(w), nF)

    return (
        ufl.inner(moment(u, d, Db1, Db2, Db12), ufl.grad(ufl.grad(v))) * dx
        - M_nn(u) * slope_jump(v) * dS
        - M_nn(v) * slope_jump(u) * dS
        + ufl.avg(alpha * D) * inv_h * slope_jump(u) * slope_jump(v) * dS
    )


def clamped_slope_nitsche(u: Expr, v: Expr, d: Expr, Db1: Expr | float, Db2: Expr | float, Db12: Expr | float,
                          alpha: Expr | float, ds: Measure, slope: Expr | None = None) -> tuple[Form, Form | None]:
    """Nitsche terms that impose the normal slope du/dn = slope on the boundary facets of ds.

    Returns (a, L): bilinear and linear parts; the value of u itself is imposed strongly.
    slope: the prescribed normal slope (UFL expression), 0 when None.
    """
    mesh = ds.ufl_domain()
    nB = ufl.FacetNormal(mesh)
    inv_h = ufl.FacetArea(mesh) / ufl.CellVolume(mesh)
    D = ufl.max_value(ufl.max_value(Db1, Db2), Db12)

    def M_nn(w: Expr) -> Expr:
        return ufl.dot(moment(w, d, Db1, Db2, Db12) * nB, nB)

    def dn(w: Expr) -> Expr:
        return ufl.dot(ufl.grad(w), nB)

    a = (-M_nn(u) * dn(v) - M_nn(v) * dn(u) + alpha * D * inv_h * dn(u) * dn(v)) * ds
    if slope is None:
        return a, None
    L = (-M_nn(v) * slope + alpha * D * inv_h * slope * dn(v)) * ds
    return a, L
