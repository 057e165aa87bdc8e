"""Coupons: n x m repeats of a unit cell as one textile (issue 7), for edge effects and variability.

`tile(textile, nx, ny)` returns a textile whose cell is nx x ny unit cells and whose yarns are the
unit cell's yarns continued over the coupon: a yarn of period p (a lattice vector of the unit cell)
becomes one yarn of period k p, the shortest multiple that is a lattice vector of the coupon, in as
many parallel copies as the coupon has room for (nx ny / k). The coupon is periodic again, so the
whole pipeline runs on it unchanged; solved, every repeat sees the same neighbours, which makes a
tiled solution equal to the unit cell's (a test checks it) until something breaks the symmetry
(free edges, per-repeat variability).
"""

from dataclasses import replace
from math import gcd

import numpy as np

from textile_fenicsx.errors import TextileError
from textile_fenicsx.textile import Cell, Textile
from textile_fenicsx.yarn import NodeSections, PositionSections


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
        section = replace(section, at_nodes=at)
    elif isinstance(section, PositionSections):  # fractions of the length: k copies, squeezed
        pos = tuple((j + f) / k for j in range(k) for f in section.positions)
        section = replace(section, positions=pos, at_positions=tuple(section.at_positions) * k)
    return replace(yarn, nodes=nodes, section=section, tangents=per_node(yarn.tangents), ups=per_node(yarn.ups),
                   angles=per_node(yarn.angles), name=name)


def tile(textile: Textile, nx: int, ny: int) -> Textile:
    """The textile repeated nx times along x and ny times along y, as one periodic cell."""
    for label, n in (("nx", nx), ("ny", ny)):
        if int(n) != n or n < 1:
            raise TextileError(f"coupon repeats {label} must be a whole number >= 1, got {n!r}")
    nx, ny = int(nx), int(ny)
    c = textile.cell
    big = Cell(nx * c.lx, ny * c.ly, c.x0, c.y0, c.z_range)
    yarns = []
    for yarn in textile.yarns:
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
    return Textile(big, yarns, name=f"{textile.name}_{nx}x{ny}", resolution=textile.resolution)
