"""Mid-surfaces of the yarns on the projected mesh, and the structure the solver couples them by.

For each yarn i (DESIGN.md sections 4-6):
- its footprint cells as a submesh (all local cells with the tag, owned and ghost, so that dS forms
  work) with P2 space Vs and the map of its dofs to the parent P2 space;
- at every P2 dof point the initial mid-height z0 = (top + bottom) / 2 and thickness t = top - bottom
  from the model's vertical rays, and the in-plane fibre direction d per cell (DG0).
Between yarns: in every cell covered by two or more yarns, the vertical stacking order (by mean z0
over the cell) and the pairs of vertically adjacent yarns (upper, lower), with the dof pairs that sit
at the same points (exact: crossing yarns share the parent's nodes).
Across the cell: for every yarn, its dofs on the right/top sides paired with their periodic images
on the left/bottom sides (global numbering, so pairs that straddle ranks are found too).
"""

import logging
from dataclasses import dataclass, field

import basix
import numpy as np
from mpi4py import MPI
from scipy.spatial import cKDTree

import dolfinx
from textile_fenicsx.common.errors import GeometryError
from textile_fenicsx.plate.mesh.conversion import GHOST
from textile_fenicsx.plate.mesh.projected import ProjectedMesh

log = logging.getLogger(__name__)

REAL, STRIP = 1, 2


@dataclass
class MidSurface:
    """One yarn's mid-surface on its footprint (lengths mm)."""

    yarn: int
    mesh: dolfinx.mesh.Mesh          # submesh of the footprint cells
    parent_cells: np.ndarray         # submesh cell -> parent cell (local indices)
    V: dolfinx.fem.FunctionSpace     # P2 on the submesh
    to_parent: np.ndarray            # submesh dof -> parent P2 dof (local indices)
    z0: dolfinx.fem.Function         # initial mid-height
    t: dolfinx.fem.Function          # thickness
    d: dolfinx.fem.Function          # in-plane unit fibre direction, DG0 vector
    cell_kind: dolfinx.mesh.MeshTags  # 1: cell of the unit cell, 2: ghost-strip copy

    def __repr__(self) -> str:
        return (f"<MidSurface of yarn {self.yarn}: {self.V.dofmap.index_map.size_global} P2 dofs, "
                f"{self.mesh.topology.index_map(2).size_global} cells>")

    @property
    def dx(self):
        """Measure over the yarn's cells in the unit cell (not the ghost strip)."""
        import ufl

        return ufl.Measure("dx", self.mesh, subdomain_data=self.cell_kind, subdomain_id=REAL)


@dataclass
class MidSurfaces:
    """All yarns' mid-surfaces on one projected mesh, with contact and periodic structure."""

    projected: ProjectedMesh
    V: dolfinx.fem.FunctionSpace                  # P2 on the whole cell (parent)
    yarns: list = field(default_factory=list)     # MidSurface per yarn
    contact: dict = field(default_factory=dict)   # (upper, lower) -> local parent cells
    contact_dofs: dict = field(default_factory=dict)  # (upper, lower) -> (n, 2) submesh dof pairs
    contact_margin: dict = field(default_factory=dict)  # (upper, lower) -> (n,) gap a node keeps [mm]
    periodic: list = field(default_factory=list)  # per yarn: (n, 2) global parent dofs (image, source)

    def __repr__(self) -> str:
        name = self.projected.textile.name if self.projected.textile is not None else "a plate"
        dofs = sum(y.V.dofmap.index_map.size_global for y in self.yarns)
        return f"<MidSurfaces of {name!r}: {len(self.yarns)} yarns, {dofs} dofs, {len(self.contact)} contact pairs>"


def _parent_space(msh):
    return dolfinx.fem.functionspace(msh, ("Lagrange", 2))


def mid_surfaces(projected: ProjectedMesh) -> MidSurfaces:
    """Sample z0, t and d of every yarn on its footprint and build the coupling structure."""
    msh = projected.mesh
    comm = msh.comm
    textile = projected.textile
    assert textile is not None  # a textile's mesh (plate_mesh's plates have none)
    V = _parent_space(msh)
    X = V.tabulate_dof_coordinates()[:, :2]
    out = MidSurfaces(projected, V)
    mean_z0 = {}
    for i in range(len(textile.yarns)):
        cells = projected.yarn_cells(i)
        n_owned = comm.allreduce(int(np.sum(cells < msh.topology.index_map(2).size_local)), op=MPI.SUM)
        if n_owned == 0:
            raise GeometryError(f"{textile.yarns[i].name} (yarn {i}) has an empty footprint on the mesh")
        sub, emap, _, _ = dolfinx.mesh.create_submesh(msh, 2, cells)
        emap = np.asarray(emap)
        Vs = dolfinx.fem.functionspace(sub, ("Lagrange", 2))
        s2p = np.empty(Vs.dofmap.index_map.size_local + Vs.dofmap.index_map.num_ghosts, dtype=np.int64)
        s2p[Vs.dofmap.list.ravel()] = V.dofmap.list[emap].ravel()
        xy = X[s2p]
        bot, top = textile.columns(xy, yarns=[i]).envelope(len(textile.yarns))
        bot, top = bot[:, i], top[:, i]
        missing = np.isnan(bot)
        if np.any(missing):  # rays grazing the footprint edge: thickness 0 at the centreline's height
            bot[missing] = top[missing] = textile.nearest_centreline(i, xy[missing])[0][:, 2]
        z0, t = dolfinx.fem.Function(Vs, name="z0"), dolfinx.fem.Function(Vs, name="t")
        z0.x.array[:] = (top + bot) / 2
        t.x.array[:] = top - bot
        W = dolfinx.fem.functionspace(sub, ("DG", 0, (2,)))
        d = dolfinx.fem.Function(W, name="d")
        mid_xy = dolfinx.mesh.compute_midpoints(sub, 2, np.arange(len(emap), dtype=np.int32))[:, :2]
        tan = textile.fibre_direction(i, mid_xy)[:, :2]
        norm = np.linalg.norm(tan, axis=1, keepdims=True)
        flat = norm[:, 0] < 1e-9  # a vertical stretch: use the yarn's overall direction
        axis = textile.yarns[i].period[:2]
        tan[flat] = axis / np.linalg.norm(axis)
        norm[flat] = 1.0
        d.x.array[:] = (tan / norm).ravel()
        kind = np.where(_parent_tag(projected, emap) < GHOST, REAL, STRIP).astype(np.int32)
        cell_kind = dolfinx.mesh.meshtags(sub, 2, np.arange(len(emap), dtype=np.int32), kind)
        out.yarns.append(MidSurface(i, sub, emap, Vs, s2p, z0, t, d, cell_kind))
        # mean z0 per parent cell, for the stacking order
        cell_dofs = Vs.dofmap.list
        mean_z0[i] = dict(zip(emap.tolist(), z0.x.array[cell_dofs].mean(axis=1).tolist()))
    _contact_structure(out, mean_z0)
    _gap_margins(out)
    textile.forget_surfaces()  # sampled: the yarns' triangles are not needed by the later stages
    _periodic_structure(out)
    dofs = [y.V.dofmap.index_map.size_global for y in out.yarns]
    log.info("midsurfaces: %d yarns, %d dofs, %d contact pairs", len(dofs), sum(dofs), len(out.contact))
    return out


def plate_surfaces(projected: ProjectedMesh, z0, t, d) -> MidSurfaces:
    """One plate covering the whole (periodic) cell, with z0 and t given as functions of x (3, N)
    and d as a constant 2-vector: for verification problems with closed-form answers."""
    msh = projected.mesh
    V = _parent_space(msh)
    cells = projected.yarn_cells(0)
    sub, emap, _, _ = dolfinx.mesh.create_submesh(msh, 2, cells)
    emap = np.asarray(emap)
    Vs = dolfinx.fem.functionspace(sub, ("Lagrange", 2))
    s2p = np.empty(Vs.dofmap.index_map.size_local + Vs.dofmap.index_map.num_ghosts, dtype=np.int64)
    s2p[Vs.dofmap.list.ravel()] = V.dofmap.list[emap].ravel()
    fz0, ft = dolfinx.fem.Function(Vs, name="z0"), dolfinx.fem.Function(Vs, name="t")
    fz0.interpolate(z0)
    ft.interpolate(t)
    fd = dolfinx.fem.Function(dolfinx.fem.functionspace(sub, ("DG", 0, (2,))), name="d")
    fd.x.array[:] = np.tile(np.asarray(d, float) / np.linalg.norm(d), len(fd.x.array) // 2)
    kind = np.where(_parent_tag(projected, emap) < GHOST, REAL, STRIP).astype(np.int32)
    cell_kind = dolfinx.mesh.meshtags(sub, 2, np.arange(len(emap), dtype=np.int32), kind)
    out = MidSurfaces(projected, V, [MidSurface(0, sub, emap, Vs, s2p, fz0, ft, fd, cell_kind)])
    _periodic_structure(out)
    return out


def _parent_tag(projected: ProjectedMesh, cells: np.ndarray) -> np.ndarray:
    """Region tag of local parent cells."""
    n = projected.mesh.topology.index_map(2)
    tag = np.zeros(n.size_local + n.num_ghosts, dtype=np.int64)
    tag[projected.cell_tags.indices] = projected.cell_tags.values
    return tag[cells]


def _crossing_orders(ms: MidSurfaces, by_tag: dict, mean_z0: dict) -> dict[tuple[int, int], float]:
    """Per pair of yarns (a, b), a < b, the sum over the owned cells they both cover of z0_a - z0_b
    (collective): positive where a lies above b over their crossing as a whole. In a sheared
    idealised cell a crossing's overlap reaches past the point where the two paths have swapped
    heights (beyond about 20 degrees for yarns 0.7 of their spacing wide, docs/shear.md), and the
    cells' own orders would contradict each other at the nodes they share. A 2D weave's warp and
    weft cross once per cell, so each pair takes the order of its crossing (only for sheared
    cells: coupons of them are refused)."""
    proj = ms.projected
    owned = proj.mesh.topology.index_map(2).size_local
    local: dict[tuple[int, int], float] = {}
    for tag, yarns in by_tag.items():
        cells = proj.cell_tags.indices[(proj.cell_tags.values == tag)]
        cells = cells[cells < owned].tolist()
        for a in yarns:
            for b in yarns:
                if a < b:
                    local[(a, b)] = local.get((a, b), 0.0) + sum(mean_z0[a][c] - mean_z0[b][c] for c in cells)
    total: dict[tuple[int, int], float] = {}
    for part in proj.mesh.comm.allgather(local):
        for key, value in part.items():
            total[key] = total.get(key, 0.0) + value
    return {**total, **{(b, a): -v for (a, b), v in total.items()}}


def _contact_structure(ms: MidSurfaces, mean_z0: dict) -> None:
    """Stacking order per multi-yarn cell and the dof pairs of vertically adjacent yarns."""
    proj = ms.projected
    by_tag = {t: s for t, s in proj.coverage.items() if len(s) >= 2}
    pairs: dict[tuple[int, int], list] = {}
    apart: dict[tuple[int, int], tuple] = {}
    crossing = _crossing_orders(ms, by_tag, mean_z0) if proj.cell is not None and proj.cell.shift else {}
    for tag, yarns in by_tag.items():
        for c in proj.cell_tags.indices[proj.cell_tags.values == tag]:
            order = sorted(yarns, key=lambda y: -mean_z0[y][int(c)])  # top first
            for k in range(len(order) - 1):  # a sheared cell: each pair in its crossing's order
                if crossing.get((order[k + 1], order[k]), 0.0) > 0:
                    order[k], order[k + 1] = order[k + 1], order[k]
            for upper, lower in zip(order[:-1], order[1:]):
                pairs.setdefault((upper, lower), []).append(int(c))
                key = (min(upper, lower), max(upper, lower))
                gap = abs(mean_z0[upper][int(c)] - mean_z0[lower][int(c)])
                if gap >= apart.get(key, (-1.0, 0))[0]:
                    apart[key] = (gap, int(c))
    _check_stacking(ms, apart)
    # the same pairs, in the same order, on every rank (some with no local cells)
    every = sorted({k for part in proj.mesh.comm.allgather(list(pairs)) for k in part})
    ms.contact = {k: np.array(sorted(pairs.get(k, [])), dtype=np.int32) for k in every}
    # dof pairs: the same parent dof seen from the two yarns' submeshes (sorted lookups, built
    # once per yarn: a dict per pair cost memory in proportion to pairs x yarn size on coupons)
    sorted_parent = [np.argsort(y.to_parent) for y in ms.yarns]

    def local_dof(y, parent):
        order = sorted_parent[y]
        k = np.searchsorted(ms.yarns[y].to_parent, parent, sorter=order)
        return order[np.minimum(k, len(order) - 1)]

    for (u, l), cells in ms.contact.items():
        parent = np.unique(ms.V.dofmap.list[cells].ravel())
        du, dl = local_dof(u, parent), local_dof(l, parent)
        if len(parent) and (np.any(ms.yarns[u].to_parent[du] != parent) or np.any(ms.yarns[l].to_parent[dl] != parent)):
            raise GeometryError(f"contact of yarns {u} and {l}: a shared node is missing from one of them")
        ms.contact_dofs[(u, l)] = np.column_stack((du, dl)).astype(np.int64).reshape(-1, 2)


# Points in each cell where the P2 gap field is compared with the model's own rays (reference
# coordinates): the centroid, the centroids of the three corner sub-triangles, and the quarter
# points of the edges (the P2 nodes themselves are exact).
MARGIN_POINTS = np.array([[1 / 3, 1 / 3], [1 / 6, 1 / 6], [2 / 3, 1 / 6], [1 / 6, 2 / 3],
                          [1 / 4, 0], [3 / 4, 0], [0, 1 / 4], [0, 3 / 4], [3 / 4, 1 / 4], [1 / 4, 3 / 4]])

# Where the corrected model's overlap is read over a pair's cells (model_margins): a lattice of
# eighths of each cell (45 points); an overlap at a binder's flank 0.05 mm across lay between the
# MARGIN_POINTS of t1.7's 0.3 mm cells
SETTLE_POINTS = basix.create_lattice(basix.CellType.triangle, 8, basix.LatticeType.equispaced, True)


def _pair_gaps(ms: MidSurfaces, u: int, l: int, w=None, dt=None) -> tuple[np.ndarray, np.ndarray]:
    """The pair's nodal gap (bottom of u less top of l, with displacements w and thickness
    changes dt if given) on the parent dofs of its cells [mm], and those dofs (c, 6)."""
    yu, yl = ms.yarns[u], ms.yarns[l]
    du, dl = ms.contact_dofs[(u, l)][:, 0], ms.contact_dofs[(u, l)][:, 1]
    lower, upper = yl.z0.x.array[dl] + yl.t.x.array[dl] / 2, yu.z0.x.array[du] - yu.t.x.array[du] / 2
    if w is not None:
        upper, lower = upper + w[u].x.array[du], lower + w[l].x.array[dl]
    if dt is not None:
        upper, lower = upper - dt[u].x.array[du] / 2, lower + dt[l].x.array[dl] / 2
    g = np.zeros(ms.V.dofmap.index_map.size_local + ms.V.dofmap.index_map.num_ghosts)
    g[yu.to_parent[du]] = upper - lower
    return g, ms.V.dofmap.list[ms.contact[(u, l)]]


def _margin_points(ref: np.ndarray = MARGIN_POINTS) -> np.ndarray:
    """The P2 basis at the reference points ref (MARGIN_POINTS), (points, 6)."""
    return basix.create_element(basix.ElementFamily.P, basix.CellType.triangle, 2,
                                basix.LagrangeVariant.gll_warped).tabulate(0, ref)[0, :, :, 0]


def _add_margins(ms: MidSurfaces, shortfall) -> float:
    """Every pair's node margins raised by `shortfall(u, l)` (per cell of the pair, >= 0 [mm]): a
    node gets the largest over the cells around it, of any pair, on any rank (a reverse scatter
    with MAX). Returns the largest added (collective)."""
    from petsc4py import PETSc

    added = dolfinx.fem.Function(ms.V)
    values = added.x.array
    for (u, l), cells in ms.contact.items():
        if len(cells):
            dofs = ms.V.dofmap.list[cells]
            np.maximum.at(values, dofs, shortfall(u, l)[:, None])
    added.x.petsc_vec.ghostUpdate(addv=PETSc.InsertMode.MAX_VALUES, mode=PETSc.ScatterMode.REVERSE)
    added.x.scatter_forward()
    for key, pairs in ms.contact_dofs.items():
        more = values[ms.yarns[key[0]].to_parent[pairs[:, 0]]]
        ms.contact_margin[key] = ms.contact_margin.get(key, np.zeros(len(pairs))) + more
    return ms.V.mesh.comm.allreduce(float(values.max(initial=0.0)), op=MPI.MAX)


def _gap_margins(ms: MidSurfaces) -> None:
    """Per contact dof, how much the P2 gap field overstates the model's gap nearby [mm] (>= 0).

    z0 and t are exact at the dofs, but between them the yarns' surfaces are not quadratic (near a
    yarn's flank its thickness falls like a square root), so a P2 gap that is >= 0 at every node
    can hide an overlap between them. In every cell of a pair the model's rays are cast at ten
    points (MARGIN_POINTS) and compared with the P2 gap there; a node's margin is the largest
    shortfall over the cells around it, of any pair, on any rank, and the solver keeps the node's
    gap >= its margin."""
    basis = _margin_points()
    textile = ms.projected.textile
    assert textile is not None  # a textile's mesh (plate_mesh's plates have none)

    # each yarn's rays once, at the points of every pair it is in: the bottom of a pair's upper
    # yarn and the top of its lower yarn there
    surface = {}
    for k in range(len(textile.yarns)):
        mine = [(pair, "bottom" if pair[0] == k else "top") for pair in ms.contact if k in pair]
        if not mine:
            continue
        xy = [_pair_points(ms, *pair) for pair, _ in mine]
        bot, top = textile.columns(np.concatenate(xy), yarns=[k]).envelope(len(textile.yarns))
        ends = np.cumsum([len(a) for a in xy])[:-1]
        for (pair, side), b, t in zip(mine, np.split(bot[:, k], ends), np.split(top[:, k], ends)):
            surface[pair, side] = b if side == "bottom" else t

    def shortfall(u, l):
        g0, dofs = _pair_gaps(ms, u, l)
        interp = g0[dofs] @ basis.T                        # (c, points): the P2 gap there
        exact = (surface[(u, l), "bottom"] - surface[(u, l), "top"]).reshape(len(dofs), -1)
        return np.nan_to_num(interp - exact, nan=0.0).max(axis=1).clip(min=0.0)

    _add_margins(ms, shortfall)


def _pair_points(ms: MidSurfaces, u: int, l: int, ref: np.ndarray = MARGIN_POINTS) -> np.ndarray:
    """The reference points ref (MARGIN_POINTS) of the pair's cells in the plane, (cells x points, 2)."""
    msh = ms.V.mesh
    corners = msh.geometry.x[msh.geometry.dofmap[ms.contact[(u, l)]]][:, :, :2]  # (c, 3, 2)
    return (corners[:, None, 0] + ref[None, :, :1] * (corners[:, None, 1] - corners[:, None, 0])
            + ref[None, :, 1:] * (corners[:, None, 2] - corners[:, None, 0])).reshape(-1, 2)


def model_margins(ms: MidSurfaces, w: list, model, source: list[int]) -> float:
    """After a correction with displacements w: where the corrected model's yarns overlap over a
    pair's cells, the cells' nodes get that depth as more margin [mm], so that the next solve keeps
    the plates that much further apart there. The sections are laid along the corrected paths, and
    round a sharp bend (a binder's crown turning into its leg, past a weft's thin edge) they reach
    beyond the column their plate reserved. source[k]: the model's yarn that plate k belongs to (a
    crown's binder); where the model's yarn has several intervals over a point (a leg beside its
    crown), the one whose middle is nearest the plate's mid-height counts. Returns the largest
    added (collective)."""
    basis = _margin_points(SETTLE_POINTS)
    n_parent = ms.V.dofmap.index_map.size_local + ms.V.dofmap.index_map.num_ghosts

    def heights(k: int, dofs: np.ndarray) -> np.ndarray:  # plate k's mid-height at the points
        y, z = ms.yarns[k], np.zeros(n_parent)
        z[y.to_parent] = y.z0.x.array + w[k].x.array
        return (z[dofs] @ basis.T).ravel()

    def shortfall(u, l):
        dofs = ms.V.dofmap.list[ms.contact[(u, l)]]
        xy = _pair_points(ms, u, l, SETTLE_POINTS)
        cols = model.columns(xy, yarns=sorted({source[u], source[l]}))
        bottom = _nearest_interval(cols, source[u], heights(u, dofs), len(xy))[0]
        top = _nearest_interval(cols, source[l], heights(l, dofs), len(xy))[1]
        return np.nan_to_num(top - bottom, nan=0.0).reshape(len(dofs), -1).max(axis=1).clip(min=0.0)

    return _add_margins(ms, shortfall)


def _nearest_interval(cols, yarn: int, z: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Per point, the bottom and top of the yarn's interval whose middle is nearest z (NaN where
    the yarn is not over the point)."""
    mine = np.flatnonzero(cols.yarn == yarn)
    point = cols.point[mine]
    far = np.abs((cols.bottom[mine] + cols.top[mine]) / 2 - z[point])
    order = np.lexsort((far, point))
    first = order[np.r_[True, point[order][1:] != point[order][:-1]]] if len(order) else order
    bottom, top = np.full(n, np.nan), np.full(n, np.nan)
    bottom[point[first]], top[point[first]] = cols.bottom[mine][first], cols.top[mine][first]
    return bottom, top


def widen_margins(ms: MidSurfaces, w: list, dt: list | None = None) -> float:
    """After a solve with displacements w (per yarn): where a pair's P2 gap field is negative
    inside a cell (a quadratic >= 0 at its nodes can dip below 0 between them), the cell's nodes
    get that depth as more margin [mm], so that the next solve keeps the field >= 0 between the
    nodes too (nodal constraints alone left 8e-5 mm^3 of the gap field negative on the orthogonal
    weave ortho_w3f4, and 1.2 % of its overlap in the corrected model). Returns the largest added
    (collective). dt: the yarns' thickness changes, where they flattened."""
    basis = _margin_points()

    def dip(u, l):
        g, dofs = _pair_gaps(ms, u, l, w, dt)
        return -(g[dofs] @ basis.T).min(axis=1).clip(max=0.0)

    return _add_margins(ms, dip)


def _check_stacking(ms: MidSurfaces, apart: dict) -> None:
    """Two yarns whose mid-heights agree (to 1e-6 mm) over all their common footprint have no
    stacking order: which is on top is not decided by the model. Name them and a place."""
    comm = ms.projected.mesh.comm
    msh = ms.projected.mesh
    local = {}
    for key, (gap, c) in apart.items():
        local[key] = (gap, dolfinx.mesh.compute_midpoints(msh, 2, np.array([c], np.int32))[0, :2].tolist())
    merged: dict[tuple[int, int], tuple] = {}
    for part in comm.allgather(local):
        for key, (gap, xy) in part.items():
            if gap >= merged.get(key, (-1.0, None))[0]:
                merged[key] = (gap, xy)
    textile = ms.projected.textile
    assert textile is not None  # a textile's mesh (plate_mesh's plates have none)
    names = [y.name for y in textile.yarns]
    for (a, b), (gap, xy) in sorted(merged.items()):
        if gap < 1e-6:
            raise GeometryError(f"{names[a]} (yarn {a}) and {names[b]} (yarn {b}) lie at the same height over "
                                f"all their common footprint (e.g. around ({xy[0]:.3f}, {xy[1]:.3f}) mm): no "
                                "stacking order decides which is on top; move one of them up or down")


def _periodic_structure(ms: MidSurfaces) -> None:
    """Per yarn, its global parent dofs on or beyond the right/top sides (the seam and the ghost
    strip) paired with their periodic images inside the cell; none when the edges are free."""
    V, comm = ms.V, ms.V.mesh.comm
    cell = ms.projected.cell
    assert cell is not None  # projected meshes are made with their cell
    if not cell.periodic:
        ms.periodic.extend(np.zeros((0, 2), np.int64) for _ in ms.yarns)
        return
    x0, x1, y0, y1 = cell.bounds
    tol = 1e-8 * max(cell.lx, cell.ly)
    imap = V.dofmap.index_map
    n_owned = imap.size_local
    X = V.tabulate_dof_coordinates()[:n_owned, :2]
    glob = imap.local_to_global(np.arange(n_owned, dtype=np.int32))
    image = (X[:, 0] > x1 - tol) | (X[:, 1] > y1 - tol)
    band = 2 * ms.projected.options.seed + (X.max(axis=0) - np.array([x1, y1])).max(initial=0)
    near = (X[:, 0] < x0 + band) | (X[:, 1] < y0 + band)
    images = comm.allgather((X[image], glob[image]))
    sources = comm.allgather((X[near], glob[near]))
    Xi = np.vstack([g[0] for g in images])
    Gi = np.concatenate([g[1] for g in images])
    Xs = np.vstack([g[0] for g in sources])
    Gs = np.concatenate([g[1] for g in sources])
    target = Xi.copy()
    if cell.shift:  # a row up is the shift along x; then back by whole cells (docs/shear.md)
        up = target[:, 1] > y1 - tol
        target[up] -= (cell.shift, cell.ly)
        target[:, 0] = x0 + np.mod(target[:, 0] - x0 + tol, cell.lx) - tol
    else:
        target[target[:, 0] > x1 - tol, 0] -= cell.lx
        target[target[:, 1] > y1 - tol, 1] -= cell.ly
    dist, k = cKDTree(Xs).query(target) if len(Xs) else (np.full(len(target), np.inf), None)
    if np.any(dist > tol):
        bad = Xi[np.argmax(dist)]
        raise GeometryError(f"the projected mesh is not periodic: the node at ({bad[0]:.6f}, {bad[1]:.6f}) "
                            "has no periodic image inside the cell")
    pairs = np.column_stack((Gi, Gs[k])) if len(Gi) else np.zeros((0, 2), np.int64)
    for y in ms.yarns:
        own = np.concatenate(comm.allgather(np.unique(imap.local_to_global(y.to_parent.astype(np.int32)))))
        # a node on the right or top side is the image of its partner only where the partner is a
        # node of the same yarn: where a yarn's edge lies on a side (a binder whose edge runs along
        # it) the partner belongs to other yarns, and the node is a free edge of this plate
        mine = np.isin(pairs[:, 0], own) & np.isin(pairs[:, 1], own)
        ms.periodic.append(pairs[mine])


def mesh_statistics(ms: MidSurfaces) -> dict:
    """JSON-ready counts and checks of a projected mesh and its mid-surfaces (collective)."""

    from textile_fenicsx.model.metrics import measure
    from textile_fenicsx.plate.mesh.footprints import footprint_area

    proj = ms.projected
    comm = proj.mesh.comm
    textile = proj.textile
    assert textile is not None  # a textile's mesh (plate_mesh's plates have none)
    volumes = measure(textile, 200, comm=comm)["yarn_volume"]["per_yarn"]
    per_yarn = []
    for y in ms.yarns:
        one = dolfinx.fem.Constant(y.mesh, 1.0)
        area = comm.allreduce(dolfinx.fem.assemble_scalar(dolfinx.fem.form(one * y.dx)), op=MPI.SUM)
        volume = comm.allreduce(dolfinx.fem.assemble_scalar(dolfinx.fem.form(y.t * y.dx)), op=MPI.SUM)
        model_area = footprint_area(textile, y.yarn)
        per_yarn.append({
            "yarn": y.yarn, "name": textile.yarns[y.yarn].name,
            "cells": comm.allreduce(int(np.sum(y.cell_kind.values[:y.mesh.topology.index_map(2).size_local] == REAL)),
                                    op=MPI.SUM),
            "dofs": y.V.dofmap.index_map.size_global,
            "footprint_area_mesh": area, "footprint_area_model": model_area,
            "thickness_integral": volume, "yarn_volume_model": volumes[y.yarn],
            "periodic_pairs": int(len(ms.periodic[y.yarn])),
        })
    stats = dict(proj.stats)
    stats["dofs_total"] = int(sum(p["dofs"] for p in per_yarn))
    stats["contact_pairs"] = sorted({k for part in comm.allgather(list(ms.contact)) for k in part})
    stats["contact_pairs"] = [list(map(int, k)) for k in stats["contact_pairs"]]
    stats["yarns"] = per_yarn
    return stats


def plate_extent(ms: MidSurfaces, w: list | None = None, dt: list | None = None) -> tuple[float, float]:
    """The lowest bottom and highest top of the plates at their nodes, z0 + w -+ (t + dt)/2 [mm],
    with the displacements w and thickness changes dt per yarn where given (collective)."""
    lo, hi = np.inf, -np.inf
    for k, y in enumerate(ms.yarns):
        z = y.z0.x.array + (0.0 if w is None else w[k].x.array)
        t = y.t.x.array + (0.0 if dt is None else dt[k].x.array)
        if len(z):
            lo, hi = min(lo, float(np.min(z - t / 2))), max(hi, float(np.max(z + t / 2)))
    comm = ms.V.mesh.comm
    return comm.allreduce(lo, op=MPI.MIN), comm.allreduce(hi, op=MPI.MAX)
