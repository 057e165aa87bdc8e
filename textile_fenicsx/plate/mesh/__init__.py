"""gmsh meshes of the textile (DESIGN.md section 4), one job per module: projected (the projected
mesh: options, type, projected_mesh), footprints (yarn outlines seen along z), regions (the gmsh
model of the covering regions), periodic_sides (opposite sides meshed alike), conversion (ghost
strip, distributed DOLFINx mesh), tiling (a coupon's mesh from its unit cell's), midsurface (each
yarn's mid-surface on the projected mesh)."""
