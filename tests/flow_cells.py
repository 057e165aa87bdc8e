"""Periodic cells with a known permeability, meshed by gmsh for the flow tests (test_flow.py).

`cylinder_cell`: one cylinder along z in the middle of a square L x L cell, i.e. a square array of
parallel cylinders, as a thin periodic slab: OpenCASCADE's box and cylinder fragmented so that the
two phases share their surface, tetrahedra sized by distance from that surface, and every face's
mesh a copy of its opposite face's (gmsh's setPeriodic with the translation across the cell), so
the flow problem finds each + face dof's image on the - face by its location.
"""

import numpy as np
from mpi4py import MPI

import dolfinx
import dolfinx.io.gmshio
from textile_fenicsx.volume.files import VolumeFields

# gmsh's physical groups: 1 + phase (0 the pores, 1 the cylinder)
PORES, CYLINDER = 1, 2


def cylinder_radius(solid_fraction: float, side: float = 1.0) -> float:
    """The radius of one cylinder per side x side square at the given solid (area) fraction."""
    return side * float(np.sqrt(solid_fraction / np.pi))


def _periodic_faces(size: tuple[float, float, float], tol: float) -> None:
    """Make the mesh of each + face of the box [0, size] the copy of the - face at its image: the
    surfaces on each face paired by their centre of mass and area (the slab's top and bottom each
    hold a disc and the square around it, both centred in the square)."""
    import gmsh

    occ = gmsh.model.occ
    surfaces = [tag for _, tag in gmsh.model.getEntities(2)]
    centre = {s: np.asarray(occ.getCenterOfMass(2, s)) for s in surfaces}
    area = {s: occ.getMass(2, s) for s in surfaces}
    bounds = {s: np.asarray(gmsh.model.getBoundingBox(2, s)).reshape(2, 3) for s in surfaces}
    for axis, length in enumerate(size):
        minus = [s for s in surfaces if np.all(np.abs(bounds[s][:, axis]) < tol)]
        plus = [s for s in surfaces if np.all(np.abs(bounds[s][:, axis] - length) < tol)]
        shift = np.zeros(3)
        shift[axis] = length
        images = []
        for s in plus:
            found = [m for m in minus if np.linalg.norm(centre[m] + shift - centre[s]) < tol
                     and abs(area[m] - area[s]) < tol * length]
            if len(found) != 1:
                raise RuntimeError(f"face {s} at {'xyz'[axis]} = {length} has {len(found)} images on the - face")
            images.append(found[0])
        if not plus or len(set(images)) != len(minus):
            raise RuntimeError(f"the {'xyz'[axis]} faces do not pair one to one: {plus} and {minus}")
        affine = np.eye(4)
        affine[axis, 3] = length
        gmsh.model.mesh.setPeriodic(2, plus, images, affine.ravel().tolist())


def _mesh_cylinder_cell(side: float, radius: float, size: float, far: float, solid_size: float) -> dict:
    """Mesh the cell in the current gmsh model (module docstring) and report what gmsh made."""
    import gmsh

    occ = gmsh.model.occ
    thickness = size  # one layer of elements or about: the flow across z does not depend on z
    box = occ.addBox(0.0, 0.0, 0.0, side, side, thickness)
    cylinder = occ.addCylinder(side / 2, side / 2, 0.0, 0.0, 0.0, thickness, radius)
    _, parents = occ.fragment([(3, box)], [(3, cylinder)])
    occ.synchronize()
    solid = [tag for _, tag in parents[1]]
    pores = [tag for _, tag in parents[0] if tag not in solid]
    if len(solid) != 1 or len(pores) != 1:
        raise RuntimeError(f"the fragments are not one cylinder and its complement: {parents}")
    _periodic_faces((side, side, thickness), tol=1e-6 * side)  # OpenCASCADE pads its bounding boxes by about 1e-7
    # the sizes: `size` on the cylinder's surface, growing to `far` 0.2 L out into the pores (the
    # narrow gaps between neighbours, 2 (L / 2 - r) wide, are within it) and quickly to
    # `solid_size` inside the cylinder, whose velocity is held at 0 (no-slip; its mesh is wasted)
    field = gmsh.model.mesh.field
    distance = field.add("MathEval")
    centre = f"{side / 2:.17g}"
    field.setString(distance, "F", f"Fabs(Sqrt((x - {centre})^2 + (y - {centre})^2) - {radius:.17g})")
    restricted = []
    for volume, largest, reach in ((pores, far, 0.2 * side), (solid, solid_size, 0.1 * side)):
        threshold = field.add("Threshold")
        field.setNumber(threshold, "InField", distance)
        field.setNumber(threshold, "SizeMin", size)
        field.setNumber(threshold, "SizeMax", largest)
        field.setNumber(threshold, "DistMin", 0.0)
        field.setNumber(threshold, "DistMax", reach)
        restrict = field.add("Restrict")
        field.setNumber(restrict, "InField", threshold)
        field.setNumbers(restrict, "VolumesList", volume)
        field.setNumber(restrict, "IncludeBoundary", 1)
        restricted.append(restrict)
    smallest = field.add("Min")
    field.setNumbers(smallest, "FieldsList", restricted)
    field.setAsBackgroundMesh(smallest)
    for option in ("MeshSizeExtendFromBoundary", "MeshSizeFromPoints", "MeshSizeFromCurvature"):
        gmsh.option.setNumber(f"Mesh.{option}", 0)
    # HXT: gmsh's default Delaunay left a sliver (minSICN 0.02-0.03) in the pores at sizes 0.04 and
    # 0.02; HXT's least there is 0.35 (Netgen's optimiser is not in Debian's gmsh)
    gmsh.option.setNumber("Mesh.Algorithm3D", 10)
    gmsh.model.addPhysicalGroup(3, pores, PORES, name="pores")
    gmsh.model.addPhysicalGroup(3, solid, CYLINDER, name="cylinder")
    gmsh.model.mesh.generate(3)
    tets = gmsh.model.mesh.getElementsByType(4)[0]
    return {"nodes": len(gmsh.model.mesh.getNodes()[0]), "tets": len(tets),
            "min_quality": float(np.min(gmsh.model.mesh.getElementQualities(tets, "minSICN")))}


def cylinder_cell(solid_fraction: float, size: float, far: float | None = None, solid_size: float = 0.2,
                  side: float = 1.0, comm: MPI.Comm = MPI.COMM_WORLD) -> tuple[VolumeFields, dict]:
    """A square array of cylinders along z at `solid_fraction`, the cell side x side x `size` [mm]
    meshed on rank 0 by gmsh (sizes: module docstring; far = 5 size unless given) and distributed:
    the VolumeFields (phase 1 the cylinder, its fibre direction z and fibre fraction 0.5, unused by
    impermeable yarns; phase 0 the pores) and gmsh's counts (rank 0's; {} elsewhere)."""
    import gmsh

    far = 5 * size if far is None else far
    report: dict | BaseException = {}
    model = None
    started = False
    if comm.rank == 0:
        started = not gmsh.isInitialized()
        if started:
            gmsh.initialize(["-noenv"], interruptible=False)
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("cylinder cell")
        try:
            report = _mesh_cylinder_cell(side, cylinder_radius(solid_fraction, side), size, far, solid_size)
            model = gmsh.model
        except Exception as error:  # told to every rank, which all raise it
            report = error
    try:
        failure = comm.bcast(report if isinstance(report, BaseException) else None, root=0)
        if failure is not None:
            raise RuntimeError(f"gmsh could not mesh the cylinder cell: {failure}") from failure
        msh, cell_tags, _ = dolfinx.io.gmshio.model_to_mesh(model, comm, 0, gdim=3)
    finally:
        if comm.rank == 0:
            gmsh.model.remove()
            if started:
                gmsh.finalize()
    owned = np.arange(msh.topology.index_map(3).size_local, dtype=np.int32)
    phase = np.full(len(owned), -1, np.int32)
    mine = cell_tags.indices < len(owned)
    phase[cell_tags.indices[mine]] = cell_tags.values[mine] - PORES
    if np.any(phase < 0):
        raise RuntimeError(f"{int(np.sum(phase < 0))} cell(s) in no physical group")
    tags = dolfinx.mesh.meshtags(msh, 3, owned, phase)
    tags.name = "phase"
    V = dolfinx.fem.functionspace(msh, ("DG", 0, (3,)))
    W = dolfinx.fem.functionspace(msh, ("DG", 0))
    direction, vf = dolfinx.fem.Function(V, name="direction"), dolfinx.fem.Function(W, name="yarn_vf")
    inside = phase == 1
    direction.x.array.reshape(-1, 3)[V.dofmap.list[owned, 0]] = np.where(inside[:, None], (0.0, 0.0, 1.0), 0.0)
    vf.x.array[W.dofmap.list[owned, 0]] = np.where(inside, 0.5, 0.0)
    direction.x.scatter_forward()  # the ghost cells' values, if the mesh has any
    vf.x.scatter_forward()
    return VolumeFields(msh, tags, direction, vf), report if comm.rank == 0 else {}
