"""Coupons: n x m repeats of a unit cell as one textile (issue 7), for edge effects and variability.

`tile(textile, nx, ny)` returns a textile whose cell is nx x ny unit cells and whose yarns are the
unit cell's yarns continued over the coupon: a yarn of period p (a lattice vector of the unit cell)
becomes one yarn of period k p, the shortest multiple that is a lattice vector of the coupon, in as
many parallel copies as the coupon has room for (nx ny / k). The coupon is periodic again, so the
whole pipeline runs on it unchanged; solved, every repeat sees the same neighbours, which makes a
tiled solution equal to the unit cell's (a test checks it) until something breaks the symmetry
(free edges, per-repeat variability).

`tile(..., free_edges=True)` cuts the coupon out of the infinite fabric instead: its cell is not
periodic, and every yarn that reaches into it is one non-periodic yarn running a period beyond
each side (so its path inside is the periodic path, end effects of the interpolation outside).
The plates then end at the coupon's sides with free edges (no constraint, no seam terms).
"""

from dataclasses import replace
from math import gcd

import numpy as np

from textile_fenicsx.common.errors import TextileError
from textile_fenicsx.common.limits import MAX_REPEATS, check_count
from textile_fenicsx.model.textile import Cell, Textile, Tiling
from textile_fenicsx.model.yarn import NodeSections, PositionSections


def _lattice_steps(yarn, cell: Cell) -> tuple[int, int]:
    """The yarn's period as whole cells (a, b) (a Textile has checked that it is one)."""
    if not yarn.periodic:
        raise TextileError(f"{yarn.name}: not periodic; only periodic yarns can be continued over a coupon")
    return int(round(yarn.period[0] / cell.lx)), int(round(yarn.period[1] / cell.ly))


def _continued(yarn, k: int, name: str):
    """The yarn followed over k of its periods (nodes, per-node data and sections repeated)."""
    if k == 1:
        return replace(yarn, name=name)
    p = yarn.period
    body = len(yarn.nodes) - 1
    nodes = np.concatenate([yarn.nodes[:-1] + j * p for j in range(k)] + [yarn.nodes[-1:] + (k - 1) * p])

    def per_node(a):
        return None if a is None else np.concatenate([a[:-1]] * k + [a[-1:]])

    section = yarn.section
    if isinstance(section, NodeSections):
        at = tuple(section.at_nodes[:body]) * k + (section.at_nodes[-1],)
        mid = tuple((seg + j * body, t, x) for j in range(k) for seg, t, x in section.mid)
        section = replace(section, at_nodes=at, mid=mid)
    elif isinstance(section, PositionSections):  # fractions of the length: k copies, squeezed
        pos = tuple((j + f) / k for j in range(k) for f in section.positions)
        section = replace(section, positions=pos, at_positions=tuple(section.at_positions) * k)
    return replace(yarn, nodes=nodes, section=section, tangents=per_node(yarn.tangents), ups=per_node(yarn.ups),
                   angles=per_node(yarn.angles), name=name)


def tile(textile: Textile, nx: int, ny: int, free_edges: bool = False) -> Textile:
    """The textile repeated nx times along x and ny times along y, as one periodic cell, or as a
    coupon with free edges."""
    for label, n in (("nx", nx), ("ny", ny)):
        try:
            whole = int(n) == n
        except (TypeError, ValueError, OverflowError):
            whole = False
        if not whole or n < 1:
            raise TextileError(f"coupon repeats {label} must be a whole number >= 1, got {n!r}")
        check_count(f"coupon repeats {label}", n, 1, MAX_REPEATS)
    nx, ny = int(nx), int(ny)
    c = textile.cell
    if c.shift:
        raise TextileError(f"coupons of a sheared cell ({c.shear_angle:.4g} degrees) are not supported yet "
                           "(docs/shear.md)")
    if not c.periodic:
        raise TextileError(f"{textile.name}: its cell has free edges already; only a periodic unit cell can be tiled")
    if free_edges:
        return _free_coupon(textile, nx, ny)
    big = Cell(nx * c.lx, ny * c.ly, c.x0, c.y0, c.z_range)
    yarns, source = [], []
    for index, yarn in enumerate(textile.yarns):
        a, b = _lattice_steps(yarn, c)
        # k: fewest periods that bring the yarn back onto itself in the coupon
        kx = nx // gcd(a % nx, nx) if a % nx else 1
        ky = ny // gcd(b % ny, ny) if b % ny else 1
        k = kx * ky // gcd(kx, ky)
        # copies: unit-cell shifts (i, j) modulo the coupon and modulo the yarn's own period
        seen = set()
        for i in range(nx):
            for j in range(ny):
                orbit = {((i + t * a) % nx, (j + t * b) % ny) for t in range(k)}
                key = min(orbit)
                if key in seen:
                    continue
                seen.add(key)
                shift = np.array([i * c.lx, j * c.ly, 0.0])
                copy = _continued(yarn, k, f"{yarn.name} [{i},{j}]")
                yarns.append(replace(copy, nodes=copy.nodes + shift, repeats=big.repeats.copy()))
                source.append(index)
    return Textile(big, yarns, name=f"{textile.name}_{nx}x{ny}", resolution=textile.resolution,
                   tiling=Tiling(textile, nx, ny, tuple(source)), thickness=textile.thickness,
                   **_plies(textile, source))


def _free_coupon(textile: Textile, nx: int, ny: int) -> Textile:
    c = textile.cell
    box = Cell(nx * c.lx, ny * c.ly, c.x0, c.y0, c.z_range, periodic=False)
    x0, x1, y0, y1 = box.bounds
    corners = np.array([[x0, y0], [x1, y0], [x0, y1], [x1, y1]])
    yarns, source = [], []
    for index, yarn in enumerate(textile.yarns):
        a, b = _lattice_steps(yarn, c)
        if b < 0 or (b == 0 and a < 0):  # the same line, walked the other way
            a, b = -a, -b
        P = yarn.period[:2]
        seen = set()
        for i in range(-1, nx + 1):
            for j in range(-1, ny + 1):
                t = j // b if b else i // a  # (i, j) and (i, j) - t (a, b) are the same yarn
                key = (i - t * a, j - t * b)
                if key in seen:
                    continue
                seen.add(key)
                shift = np.array([key[0] * c.lx, key[1] * c.ly])
                # whole periods from before the box to beyond it, one more on each side
                tau = (corners - yarn.nodes[0, :2] - shift) @ P / (P @ P)
                first, last = int(np.floor(tau.min())) - 1, int(np.ceil(tau.max())) + 1
                copy = _continued(yarn, last - first, f"{yarn.name} [{key[0]},{key[1]}]")
                move = np.r_[shift + first * P, 0.0]
                copy = replace(copy, nodes=copy.nodes + move, periodic=False, repeats=np.zeros((0, 3)))
                if _enters(copy, textile.resolution.section_points, box):
                    yarns.append(copy)
                    source.append(index)
    return Textile(box, yarns, name=f"{textile.name}_{nx}x{ny}_free", resolution=textile.resolution,
                   tiling=Tiling(textile, nx, ny, tuple(source)), thickness=textile.thickness,
                   **_plies(textile, source))


def _plies(textile: Textile, source: list[int]) -> dict:
    """A stack's plies in its coupon: the copies come yarn by yarn, so ply by ply as the unit
    cell's yarns do; each ply has its yarns' copies."""
    if textile.plies == 1:
        return {}
    from textile_fenicsx.model.plies import ply_of

    sizes = np.bincount(np.asarray(ply_of(textile))[source], minlength=textile.plies)
    return {"plies": textile.plies, "ply_sizes": tuple(int(n) for n in sizes)}


def _enters(yarn, section_points: int, box: Cell) -> bool:
    """Does the yarn's outline seen along z reach into the box (by more than a micrometre)?"""
    s = yarn.stations(0.05 * min(box.lx, box.ly))
    pos, _, up, side = yarn.frames(s)
    sec = yarn.section_points(s, section_points)
    xy = (pos[:, None, :2] + sec[..., :1] * side[:, None, :2] + sec[..., 1:] * up[:, None, :2]).reshape(-1, 2)
    x0, x1, y0, y1 = box.bounds
    tol = 1e-3
    return bool(np.any((xy[:, 0] > x0 + tol) & (xy[:, 0] < x1 - tol) & (xy[:, 1] > y0 + tol) & (xy[:, 1] < y1 - tol)))
