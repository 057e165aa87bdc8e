"""The unknowns: one per yarn dof that is not a periodic image, numbered once (DESIGN.md 6);
two where the yarns flatten (the heights of the yarn's bottom and top surfaces: `surfaces=2`).

`Periodicity` is the one owner of this numbering. Every yarn dof on the right/top seam or in the
ghost strip is a slave of its image inside the cell; `unknown(i, parent_dofs)` resolves slaves to
their masters and returns the unknowns' global indices, and `yarn_map(y)` is the sparse map R_i
(yarn dofs -> unknowns, one 1 per row) that the plates are reduced with: K = sum R_i^T A_i R_i.
With two surfaces, each yarn's unknowns on a rank are its bottom surface's then its top's, in the
same order; `surface` (BOTTOM, TOP) picks one. With one, both name the same unknowns.
"""

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

import dolfinx
from textile_fenicsx.plate.mesh.midsurface import REAL, MidSurface, MidSurfaces
from textile_fenicsx.plate.solver.linear import SolverError

__all__ = ["BOTTOM", "TOP", "Periodicity", "seam_facet_tags"]

# the surface of a yarn an unknown moves (the same unknown for both where the yarns keep their thickness)
BOTTOM, TOP = 0, 1


class Periodicity:
    """Global numbering of the unknowns: per rank, per yarn, the owned master dofs. Frozen once
    built; every rank can look up any yarn dof's unknown."""

    def __init__(self, ms: MidSurfaces, surfaces: int = 1):
        if surfaces not in (1, 2):
            raise ValueError(f"a yarn has one or two surfaces of unknowns, not {surfaces}")
        V, comm = ms.V, ms.V.mesh.comm
        self.surfaces = surfaces
        imap = V.dofmap.index_map
        self.comm = comm
        self.parent_global = imap.local_to_global(np.arange(imap.size_local + imap.num_ghosts, dtype=np.int32))
        self._parent_owners = np.concatenate([np.full(imap.size_local, comm.rank, np.int32), imap.owners])
        self.images = []
        for pairs in ms.periodic:
            order = np.argsort(pairs[:, 0])
            self.images.append((pairs[order, 0], pairs[order, 1]))
        # each yarn dof is counted once, by the rank that owns it in the yarn's submesh (a parent
        # dof's owner need not hold a cell of that yarn: ghosts are shared by facets, not vertices)
        masters = []
        for y in ms.yarns:
            glob = self.parent_global[y.to_parent[:y.V.dofmap.index_map.size_local]]
            masters.append(np.sort(glob[~np.isin(glob, self.images[y.yarn][0])]))
        n_local = int(sum(len(m) for m in masters)) * surfaces
        self.start = comm.exscan(n_local) or 0
        self.n = comm.allreduce(n_local, op=MPI.SUM)
        self.n_local = n_local
        # parent global dof -> unknown, per yarn, known on every rank (gathered once)
        pos, mine = self.start, []
        for m in masters:
            mine.append((m, np.arange(pos, pos + len(m), dtype=np.int64)))
            pos += len(m) * surfaces
        every = comm.allgather(mine)
        self.lookup = []
        for i in range(len(ms.yarns)):
            keys = np.concatenate([part[i][0] for part in every])
            vals = np.concatenate([part[i][1] for part in every])
            order = np.argsort(keys)
            self.lookup.append((keys[order], vals[order]))
        # where each yarn's bottom unknowns begin on each rank, and how many (the top's follow them)
        self._counts = [len(m) for m in masters]
        counts = np.array(comm.allgather(self._counts), dtype=np.int64).reshape(comm.size, len(masters))
        starts = np.array(comm.allgather(self.start), dtype=np.int64)[:, None] + surfaces * np.concatenate(
            [np.zeros((comm.size, 1), np.int64), np.cumsum(counts, axis=1)[:, :-1]], axis=1)
        self._yarn_counts, self._yarn_starts = counts.T.copy(), starts.T.copy()

    def unknown(self, i: int, parent_global: np.ndarray, surface: int = BOTTOM) -> np.ndarray:
        """Unknown index of yarn i at parent global dofs (slaves resolved to their masters), of
        its bottom or top surface (the same where there is one)."""
        img_keys, img_vals = self.images[i]
        master = np.asarray(parent_global, dtype=np.int64).copy()
        if len(img_keys):
            k = np.minimum(np.searchsorted(img_keys, master), len(img_keys) - 1)
            hit = img_keys[k] == master
            master[hit] = img_vals[k[hit]]
        keys, vals = self.lookup[i]
        k = np.minimum(np.searchsorted(keys, master), max(len(keys) - 1, 0))
        if len(master) and (len(keys) == 0 or np.any(keys[k] != master)):
            raise SolverError(f"yarn {i}: a dof has no master unknown (its periodic image is not a dof of the "
                              "yarn: the footprint is not periodic on the mesh)")
        if surface == TOP and self.surfaces == 2:  # the top's follow the bottom's on their rank
            rank = np.searchsorted(self._yarn_starts[i], vals[k], side="right") - 1
            return vals[k] + self._yarn_counts[i][rank]
        return vals[k]

    def surface_pairs(self, unknowns: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For global unknowns (surfaces=2), the bottom's and the top's unknown of their node and
        the surface's sign (-1 bottom, +1 top); any rank's unknowns."""
        starts, counts = self._yarn_starts.T.ravel(), self._yarn_counts.T.ravel()  # rank by rank, yarn by yarn
        u = np.asarray(unknowns, dtype=np.int64)
        block = np.searchsorted(starts, u, side="right") - 1
        offset, n = u - starts[block], counts[block]
        top = offset >= n
        bottom = starts[block] + np.where(top, offset - n, offset)
        return bottom, bottom + n, np.where(top, 1.0, -1.0)

    def local_surfaces(self, one: np.ndarray) -> np.ndarray:
        """This rank's part of a vector over one surface's unknowns (a numbering with surfaces=1 of
        the same mesh) as a vector over both: each yarn's values on its bottom and its top."""
        if self.surfaces == 1:
            return one.copy()
        parts, at = [], 0
        for n in self._counts:
            parts += [one[at:at + n], one[at:at + n]]
            at += n
        return np.concatenate(parts + [np.zeros(0)])

    def parent_owner(self, local: np.ndarray) -> np.ndarray:
        """The ranks owning local parent dofs."""
        return self._parent_owners[local]

    def image_dofs(self, ms: MidSurfaces) -> list[np.ndarray]:
        """Per yarn, which of its local dofs (owned and ghost) are periodic images (slaves)."""
        return [np.isin(self.parent_global[y.to_parent], self.images[y.yarn][0]) for y in ms.yarns]

    def yarn_unknowns(self, y: MidSurface, dofs: np.ndarray, surface: int = BOTTOM) -> np.ndarray:
        """Unknowns of yarn y's local dofs (of its bottom or top surface)."""
        return self.unknown(y.yarn, self.parent_global[y.to_parent[dofs]], surface)

    def column_parents(self, y: MidSurface, cols: np.ndarray) -> np.ndarray:
        """Global parent dofs of yarn y's dofs given by their global index in y's space, which may
        be another rank's (an assembled row's columns); collective. `release()` frees the cache."""
        cache = self.__dict__.setdefault("_parents", {})
        if y.yarn not in cache:
            imap = y.V.dofmap.index_map
            cache[y.yarn] = PETSc.Vec().createMPI((imap.size_local, imap.size_global), comm=self.comm)
            cache[y.yarn].getArray()[:] = self.parent_global[y.to_parent[:imap.size_local]]
        owned = cache[y.yarn]
        wanted, back = np.unique(cols, return_inverse=True)
        got = PETSc.Vec().createSeq(len(wanted), comm=PETSc.COMM_SELF)
        index = PETSc.IS().createGeneral(wanted.astype(PETSc.IntType), comm=PETSc.COMM_SELF)
        scatter = PETSc.Scatter().create(owned, index, got, None)
        scatter.scatter(owned, got, addv=PETSc.InsertMode.INSERT_VALUES, mode=PETSc.ScatterMode.FORWARD)
        parents = np.rint(got.getArray()).astype(np.int64)[back]
        for obj in (got, index, scatter):
            obj.destroy()
        return parents

    def release(self) -> None:
        """Free the cached vectors of column_parents."""
        for vec in self.__dict__.pop("_parents", {}).values():
            vec.destroy()

    def vector(self) -> PETSc.Vec:
        """A zero vector over the unknowns."""
        v = PETSc.Vec().createMPI((self.n_local, self.n), comm=self.comm)
        v.set(0.0)
        return v

    def yarn_map(self, y: MidSurface, surface: int = BOTTOM) -> PETSc.Mat:
        """R: yarn y's dofs (owned rows) -> unknowns (of its bottom or top surface), one 1 per row."""
        imap = y.V.dofmap.index_map
        cols = self.yarn_unknowns(y, np.arange(imap.size_local, dtype=np.int32), surface)  # owned rows in order
        R = PETSc.Mat().createAIJ(((imap.size_local, imap.size_global), (self.n_local, self.n)), comm=self.comm)
        indptr = np.arange(imap.size_local + 1, dtype=PETSc.IntType)
        R.setPreallocationCSR((indptr, cols.astype(PETSc.IntType), np.ones(len(cols), PETSc.ScalarType)))
        R.assemble()
        return R


def seam_facet_tags(y: MidSurface) -> dolfinx.mesh.MeshTags:
    """Interior facets of a yarn's submesh that touch a cell of the unit cell (tag 1): the interior
    facets of its footprint and the periodic seam facets between the cell and the ghost strip."""
    msh = y.mesh
    tdim = msh.topology.dim
    msh.topology.create_connectivity(tdim - 1, tdim)
    f2c = msh.topology.connectivity(tdim - 1, tdim)
    n_facets = msh.topology.index_map(tdim - 1).size_local + msh.topology.index_map(tdim - 1).num_ghosts
    kind = np.zeros(msh.topology.index_map(tdim).size_local + msh.topology.index_map(tdim).num_ghosts, np.int32)
    kind[y.cell_kind.indices] = y.cell_kind.values
    offsets, links = f2c.offsets[: n_facets + 1], f2c.array
    two = np.flatnonzero(np.diff(offsets) == 2)
    first, second = links[offsets[two]], links[offsets[two] + 1]
    marked = two[(kind[first] == REAL) | (kind[second] == REAL)].astype(np.int32)
    return dolfinx.mesh.meshtags(msh, tdim - 1, marked, np.ones(len(marked), np.int32))
