"""UFL forms of the plate model, one physical term each (DESIGN.md section 5).

Pure UFL: no PETSc, no I/O. Every function takes UFL objects (trial/test functions or Functions,
coefficients, measures) and returns a UFL form or expression.
"""

from textile_fenicsx.forms.bending import (
    c0ip_bending,
    clamped_slope_nitsche,
    curvature,
    fibre_frame,
    moment,
)

__all__ = ["c0ip_bending", "clamped_slope_nitsche", "curvature", "fibre_frame", "moment"]
