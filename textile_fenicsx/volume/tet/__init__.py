"""The conforming periodic tet mesher (gmsh OpenCASCADE), one job per module: mesher (the policy for
yarns in contact and the entry, tet_mesh), options (TetOptions, TetMesh, the gap, the box and its
size check), sizes (the element sizes, gmsh's background field), surface_mesh (the gmsh session,
the solids in the box and their surface mesh, with its retries), volume_mesh (the 3D mesh, with
its retry, read back as arrays), elements (periodic nodes snapped, flat tets refused, fibre
directions), report (the yarns' volumes and the mesh report); and their parts: solids (the yarn
solids in OpenCASCADE), sides (where the box's sides cut the yarns), checks (the model's gaps and
the mesh's checks, pure numpy).
"""
