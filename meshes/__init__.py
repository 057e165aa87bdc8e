"""gmsh meshes of the textile: the projected-region mesh of the unit cell and mid-surface sampling
(DESIGN.md section 4)."""
