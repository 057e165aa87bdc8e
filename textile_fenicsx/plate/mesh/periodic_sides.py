"""Periodic sides of the gmsh model (DESIGN.md section 4, step 2): opposite sides of the cell meshed
alike, node for node.

Footprint outline points near a side are put onto it (`snap_to_sides`), the cell's box gets a
vertex wherever an outline meets a side, on both sides of each pair (`side_marks`,
`box_with_marks`), and each right (top) boundary curve is declared gmsh's periodic copy of the left
(bottom) one it pairs with (`periodic_sides`).
"""

import numpy as np

from textile_fenicsx.common.errors import GeometryError
from textile_fenicsx.model.textile import Cell

__all__ = ["box_with_marks", "outlines_on_sides", "periodic_sides", "side_marks", "snap_to_sides"]


def snap_to_sides(points: np.ndarray, cell: Cell, tol: float) -> np.ndarray:
    """Footprint outline points within tol of a cell side line (or of one of its periodic copies)
    put onto it. gmsh's boolean tolerance (tol) would otherwise merge such a point onto the side
    on one side of the cell and leave its periodic copy beside the other (a binder's edge 0.0125 mm
    inside the top side: its copy lies outside the bottom side). Coordinates are compared modulo
    the cell, so every periodic copy of a point moves alike."""
    if not cell.periodic or tol <= 0:
        return points
    out = points.copy()
    for axis, lo, length in ((0, cell.bounds[0], cell.lx), (1, cell.bounds[2], cell.ly)):
        line = lo + np.round((out[:, axis] - lo) / length) * length
        near = np.abs(out[:, axis] - line) < tol
        out[near, axis] = line[near]
    return out


def outlines_on_sides(outlines: list, cell: Cell, tol: float) -> list:
    """snap_to_sides on both side chains of every footprint piece, [(yarn, [(right, left), ...])]."""
    return [(i, [(snap_to_sides(r, cell, tol), snap_to_sides(l_, cell, tol)) for r, l_ in sides])
            for i, sides in outlines]


def side_marks(chains: list[np.ndarray], cell: Cell, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Where footprint outlines (polylines) meet the cell's sides, as coordinates along them: the
    y of every meeting with x = x0 + k lx and the x of every meeting with y = y0 + k ly, each
    wrapped into the cell. Both sides of a pair get a vertex at each, so that their curves pair
    one to one (gmsh's periodic meshing needs that, and a yarn edge that ends on one side need not
    end on the other)."""
    x0, x1, y0, y1 = cell.bounds
    marks: list[list[np.ndarray]] = [[], []]
    for chain in chains:
        for axis, lo, length in ((0, x0, cell.lx), (1, y0, cell.ly)):
            other = 1 - axis
            rel = (chain[:, axis] - lo) / length
            k = np.round(rel)
            on = np.abs(rel - k) * length < 1e-9 * length
            marks[axis].append(chain[on, other])
            # crossings of a line between consecutive points
            a, b = chain[:-1], chain[1:]
            fa, fb = np.floor((a[:, axis] - lo) / length), np.floor((b[:, axis] - lo) / length)
            cross = (fa != fb) & ~on[:-1] & ~on[1:]
            if np.any(cross):
                line = lo + np.maximum(fa[cross], fb[cross]) * length
                t = (line - a[cross, axis]) / (b[cross, axis] - a[cross, axis])
                marks[axis].append(a[cross, other] + t * (b[cross, other] - a[cross, other]))
    out = []
    for axis, (lo, length) in enumerate(((y0, cell.ly), (x0, cell.lx))):
        v = np.concatenate(marks[axis]) if marks[axis] else np.zeros(0)
        v = lo + np.mod(v - lo, length)
        v = np.unique(np.round(v, 9))
        v = v[(v - lo > tol) & (lo + length - v > tol)]  # not at the corners
        if len(v) > 1:  # one vertex for marks closer than the tolerance
            v = v[np.r_[True, np.diff(v) > tol]]
        out.append(v)
    return out[0], out[1]


def box_with_marks(cell: Cell, on_x: np.ndarray, on_y: np.ndarray) -> int:
    """The cell as a polygon surface with vertices at the marks, on both sides of each pair."""
    import gmsh

    occ = gmsh.model.occ
    x0, x1, y0, y1 = cell.bounds
    ring = ([(x, y0) for x in np.r_[x0, on_y]] + [(x1, y) for y in np.r_[y0, on_x]]
            + [(x, y1) for x in np.r_[x1, on_y[::-1]]] + [(x0, y) for y in np.r_[y1, on_x[::-1]]])
    pts = [occ.addPoint(px, py, 0) for px, py in ring]
    lines = [occ.addLine(pts[k], pts[(k + 1) % len(pts)]) for k in range(len(pts))]
    return occ.addPlaneSurface([occ.addCurveLoop(lines)])


def periodic_sides(cell: Cell, sliver: float) -> None:
    """Periodic sides: each right (top) boundary curve is a translated copy of a left (bottom) one;
    pair them by their centres of mass and make gmsh mesh them alike."""
    import gmsh

    occ = gmsh.model.occ
    x0, x1, y0, y1 = cell.bounds
    tol = max(sliver, 1e-6 * max(cell.lx, cell.ly))
    curves = [c for _, c in gmsh.model.getEntities(1)]
    centres = np.array([occ.getCenterOfMass(1, c) for c in curves]).reshape(-1, 3)
    for axis, (lo, hi) in ((0, (x0, x1)), (1, (y0, y1))):
        on_lo = [k for k, c in enumerate(curves) if _on_line(curves[k], axis, lo, tol)]
        on_hi = [k for k, c in enumerate(curves) if _on_line(curves[k], axis, hi, tol)]
        shift = np.zeros(3)
        shift[axis] = hi - lo
        masters, slaves = [], []
        for k in on_lo:
            d = np.linalg.norm(centres[on_hi] - (centres[k] + shift), axis=1) if on_hi else np.array([np.inf])
            j = int(np.argmin(d))
            if d[j] > tol:
                raise GeometryError(f"periodic boundary curves do not match across the cell: the curve "
                                    f"centred at {np.round(centres[k, :2], 4).tolist()} has no copy at "
                                    f"{'x' if axis == 0 else 'y'} = {hi:.4f} mm")
            masters.append(curves[k])
            slaves.append(curves[on_hi[j]])
        if len(set(slaves)) != len(on_hi):
            raise GeometryError(f"periodic boundary curves do not pair one to one along "
                                f"{'x' if axis == 0 else 'y'} ({len(on_lo)} vs {len(on_hi)} curves)")
        T = np.eye(4)
        T[axis, 3] = hi - lo
        gmsh.model.mesh.setPeriodic(1, slaves, masters, T.ravel().tolist())


def _on_line(curve: int, axis: int, value: float, tol: float) -> bool:
    """Does gmsh curve `curve` lie on the line x[axis] = value (within tol)? Judged by points along
    it, not by its bounding box: OpenCASCADE grows a box by its vertices' tolerance, which a
    boolean with a tolerance raises (a side's curve 0.1 mm long whose box reached 0.028 mm past
    the side, beyond a tolerance of 0.025 mm, was left out of the pairs and meshed unlike its copy)."""
    import gmsh

    lo, hi = gmsh.model.getParametrizationBounds(1, curve)
    points = np.reshape(gmsh.model.getValue(1, curve, np.linspace(lo[0], hi[0], 5).tolist()), (-1, 3))
    return bool(np.all(np.abs(points[:, axis] - value) < tol))


