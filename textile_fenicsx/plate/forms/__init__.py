"""UFL forms of the plate model, one physical term each (DESIGN.md section 5): bending (C0 interior
penalty), membrane (tension, foundation, load), contact, the yarns' compaction law (compression).
The cell problems' forms live beside them in homogenisation/.

Pure UFL: no PETSc, no I/O. Every function takes UFL objects (trial/test functions or Functions,
coefficients, measures) and returns a UFL form or expression.
"""

from textile_fenicsx.plate.forms.bending import c0ip_bending, clamped_slope_nitsche, curvature, fibre_frame, moment
from textile_fenicsx.plate.forms.contact import contact_energy, contact_forms, penetration_volume, stiffness
from textile_fenicsx.plate.forms.membrane import foundation, load, tension

__all__ = ["c0ip_bending", "clamped_slope_nitsche", "contact_energy", "contact_forms", "curvature", "fibre_frame",
           "foundation", "load", "moment", "penetration_volume", "stiffness", "tension"]
