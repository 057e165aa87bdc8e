"""The volume stage (DESIGN.md section 12): the cell's box (box), the voxel mesher (voxel), the
conforming tet mesher (tet/), the stage's entry (stage: volume_mesh, mesh_cell) and
the mesh in DOLFINx with its files (files).
"""
