"""Homogenisation of a periodic unit cell: effective stiffness and thermal conductivity
(DESIGN.md section 12).

    from textile_fenicsx.homogenisation import homogenise
    result = homogenise(mesh, cell_tags, direction, yarn_vf, fibre="t300", matrix="epoxy")

Modules, one job each: materials (constituents, presets, TOML files, Chamis' yarn), constants
(Voigt notation, engineering constants, rotations, bounds), fields (per-cell properties as DG0
fields), periodic (node check, multi-point constraint, pin), cellproblem (CG + GAMG on the
constrained system, energies), elasticity and conduction (the two cell problems), effective
(the entry point and its result).
"""

from textile_fenicsx.homogenisation.constants import VOIGT_ORDER, engineering_constants
from textile_fenicsx.homogenisation.effective import (
    Homogenised,
    HomogeniseOptions,
    estimated_bytes,
    homogenise,
    homogenise_fields,
)
from textile_fenicsx.homogenisation.fields import CellFields, phase_fields, yarn_fields
from textile_fenicsx.homogenisation.materials import (
    PRESETS,
    Isotropic,
    Orthotropic,
    TransverselyIsotropic,
    material,
    read_material,
    yarn_material,
)

__all__ = ["PRESETS", "VOIGT_ORDER", "CellFields", "Homogenised", "HomogeniseOptions", "Isotropic", "Orthotropic",
           "TransverselyIsotropic", "engineering_constants", "estimated_bytes", "homogenise", "homogenise_fields",
           "material", "phase_fields", "read_material", "yarn_fields", "yarn_material"]
