"""UFL forms, one physical term each: the plate model (DESIGN.md section 5) and the periodic cell
problems of homogenisation (elasticity, conduction; section 12).

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
from textile_fenicsx.forms.conduction import conduction_cell_forms, heat_flux
from textile_fenicsx.forms.contact import contact_energy, contact_forms, penetration_volume, stiffness
from textile_fenicsx.forms.elasticity import (
    elastic_cell_forms,
    elastic_energy_density,
    strain,
    voigt_strain,
    voigt_stress,
)
from textile_fenicsx.forms.membrane import foundation, load, tension

__all__ = ["c0ip_bending", "clamped_slope_nitsche", "conduction_cell_forms", "contact_energy", "contact_forms",
           "curvature", "elastic_cell_forms", "elastic_energy_density", "fibre_frame", "foundation", "heat_flux",
           "load", "moment", "penetration_volume", "stiffness", "strain", "tension", "voigt_strain",
           "voigt_stress"]
