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
        moved = _row_shift(out, cell) if axis == 0 else 0.0  # a sheared cell's x sides move row by row
        line = lo + moved + np.round((out[:, axis] - lo - moved) / length) * length
        near = np.abs(out[:, axis] - line) < tol
        out[near, axis] = line[near]
    return out


def _row_shift(points: np.ndarray, cell: Cell) -> np.ndarray | float:
    """How far along x the copies of the cell's x sides are moved in the row of cells each point
    lies in (Cell.shift per row up; 0 for an unsheared cell)."""
    if not cell.shift:
        return 0.0
    return np.floor((points[:, 1] - cell.y0) / cell.ly) * cell.shift


def outlines_on_sides(outlines: list, cell: Cell, tol: float) -> list:
    """snap_to_sides on both side chains of every footprint piece, [(yarn, [(right, left), ...])]."""
    if cell.shift:
        return [(i, [(_chain_on_sides(r, cell, tol), _chain_on_sides(l_, cell, tol)) for r, l_ in sides])
                for i, sides in outlines]
    return [(i, [(snap_to_sides(r, cell, tol), snap_to_sides(l_, cell, tol)) for r, l_ in sides])
            for i, sides in outlines]


def _chain_on_sides(chain: np.ndarray, cell: Cell, tol: float) -> np.ndarray:
    """snap_to_sides on a side chain of a sheared cell, keeping one point of each run that comes
    within tol of an x side: a sheared yarn's edge crosses the x sides at the shear's angle from
    them (15 degrees: TexGen's satin at 15, points 0.125 mm apart, two of them 0.017 and 0.014 mm
    from the side), and two neighbours put on the side made the spline run along it, which
    OpenCASCADE cut at one more point on one side of the cell than on the other."""
    moved = _row_shift(chain, cell)
    rel = (chain[:, 0] - cell.x0 - moved) / cell.lx
    near = np.abs(rel - np.round(rel)) * cell.lx < tol
    keep = np.ones(len(chain), bool)
    k = 0
    while k < len(chain):
        if not near[k]:
            k += 1
            continue
        end = k
        while end + 1 < len(chain) and near[end + 1]:
            end += 1
        if end > k:  # the run's point nearest the side stays (to be put on it), the others go
            run = np.arange(k, end + 1)
            best = run[np.argmin(np.abs(rel[run] - np.round(rel[run])))]
            keep[run[run != best]] = False
        k = end + 1
    return snap_to_sides(chain[keep], cell, tol)


def side_marks(chains: list[np.ndarray], cell: Cell, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Where footprint outlines (polylines) meet the cell's sides, as coordinates along them: the
    y of every meeting with x = x0 + k lx and the x of every meeting with y = y0 + k ly, each
    wrapped into the cell. Both sides of a pair get a vertex at each, so that their curves pair
    one to one (gmsh's periodic meshing needs that, and a yarn edge that ends on one side need not
    end on the other)."""
    x0, x1, y0, y1 = cell.bounds
    marks: list[list[np.ndarray]] = [[], []]
    for chain in chains:
        if cell.shift:  # in a row of its own each stretch meets that row's x sides (docs/shear.md)
            chain = _split_at_rows(chain, cell)
        for axis, lo, length in ((0, x0, cell.lx), (1, y0, cell.ly)):
            other = 1 - axis
            rel = (chain[:, axis] - lo) / length
            k = np.round(rel)
            on = np.abs(rel - k) * length < 1e-9 * length
            if axis == 1 and cell.shift:  # a meeting with y = y0 + k ly is the bottom side's point k shifts back
                marks[axis].append(chain[on, other] - k[on] * cell.shift)
            elif axis == 0 and cell.shift:
                moved = _row_shift(chain, cell)
                rel = (chain[:, 0] - lo - moved) / length
                on = np.abs(rel - np.round(rel)) * length < 1e-9 * length
                marks[axis].append(chain[on, other])
            else:
                marks[axis].append(chain[on, other])
            # crossings of a line between consecutive points
            a, b = chain[:-1], chain[1:]
            moved = np.zeros(len(a))
            if axis == 0 and cell.shift:  # each stretch within one row: that row's x sides
                moved = np.floor(((a[:, 1] + b[:, 1]) / 2 - y0) / cell.ly) * cell.shift
                fa, fb = np.floor((a[:, 0] - lo - moved) / length), np.floor((b[:, 0] - lo - moved) / length)
            else:
                fa, fb = np.floor((a[:, axis] - lo) / length), np.floor((b[:, axis] - lo) / length)
            cross = (fa != fb) & ~on[:-1] & ~on[1:]
            if np.any(cross):
                line = lo + np.maximum(fa[cross], fb[cross]) * length + moved[cross]
                t = (line - a[cross, axis]) / (b[cross, axis] - a[cross, axis])
                at = a[cross, other] + t * (b[cross, other] - a[cross, other])
                if axis == 1 and cell.shift:
                    at = at - np.maximum(fa[cross], fb[cross]) * cell.shift
                marks[axis].append(at)
    out = []
    for axis, (lo, length) in enumerate(((y0, cell.ly), (x0, cell.lx))):
        v = np.concatenate(marks[axis]) if marks[axis] else np.zeros(0)
        v = lo + np.mod(v - lo, length)
        v = np.unique(np.round(v, 9))
        v = v[(v - lo > tol) & (lo + length - v > tol)]  # not at the corners
        if axis == 1 and cell.shift:  # the top corner's image on the bottom side, as a corner is kept
            image = x0 + np.mod(-cell.shift, cell.lx)  # (its image on the top side is box_with_marks')
            v = v[np.abs(v - image) > tol]
            if image - lo > tol and lo + length - image > tol:
                v = np.sort(np.r_[v, image])
        if len(v) > 1:  # one vertex for marks closer than the tolerance
            v = v[np.r_[True, np.diff(v) > tol]]
        out.append(v)
    return out[0], out[1]


def _split_at_rows(chain: np.ndarray, cell: Cell) -> np.ndarray:
    """The polyline with a point added wherever it crosses a line y = y0 + k ly between two of its
    points: each stretch then lies in one row of cells."""
    rows = np.floor((chain[:, 1] - cell.y0) / cell.ly)
    out = [chain[:1]]
    for a, b, ra, rb in zip(chain[:-1], chain[1:], rows[:-1], rows[1:]):
        if ra != rb:
            lines = cell.y0 + cell.ly * np.arange(min(ra, rb) + 1, max(ra, rb) + 1)
            t = np.sort((lines - a[1]) / (b[1] - a[1]))
            out.append(a + t[:, None] * (b - a))
        out.append(b[None])
    return np.vstack(out)


def box_with_marks(cell: Cell, on_x: np.ndarray, on_y: np.ndarray) -> int:
    """The cell as a polygon surface with vertices at the marks, on both sides of each pair (on the
    top side of a sheared cell, at the bottom's marks moved by its shift, wrapped into the cell)."""
    import gmsh

    occ = gmsh.model.occ
    x0, x1, y0, y1 = cell.bounds
    on_top = on_y
    if cell.shift:  # and at the bottom corner's image
        on_top = np.sort(x0 + np.mod(np.r_[on_y, x0] + cell.shift - x0, cell.lx))
        on_top = on_top[(on_top - x0 > 1e-9 * cell.lx) & (x1 - on_top > 1e-9 * cell.lx)]
    ring = ([(x, y0) for x in np.r_[x0, on_y]] + [(x1, y) for y in np.r_[y0, on_x]]
            + [(x, y1) for x in np.r_[x1, on_top[::-1]]] + [(x0, y) for y in np.r_[y1, on_x[::-1]]])
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
        masters, slaves, moves = [], [], []
        for k in on_lo:
            move = 0.0
            if axis == 1 and cell.shift:  # the top's copy: shifted along x, back by whole cells into it
                move = shift[0] = _whole_move(cell, x0 + np.mod(centres[k, 0] + cell.shift - x0, cell.lx)
                                              - centres[k, 0])
            moves.append(move)
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
        for move in sorted(set(moves)):  # one translation per group (one only without a shift)
            T = np.eye(4)
            T[axis, 3] = hi - lo
            T[0, 3] += move
            group = [k for k, m in enumerate(moves) if m == move]
            gmsh.model.mesh.setPeriodic(1, [slaves[k] for k in group], [masters[k] for k in group], T.ravel().tolist())


def _whole_move(cell: Cell, move: float) -> float:
    """A move along x [mm] that is the shift less whole cells, to the bit: shift - k lx for the
    nearest whole k."""
    return float(cell.shift - cell.lx * np.round((cell.shift - move) / cell.lx))


def _on_line(curve: int, axis: int, value: float, tol: float) -> bool:
    """Does gmsh curve `curve` lie on the line x[axis] = value (within tol)? Judged by points along
    it, not by its bounding box: OpenCASCADE grows a box by its vertices' tolerance, which a
    boolean with a tolerance raises (a side's curve 0.1 mm long whose box reached 0.028 mm past
    the side, beyond a tolerance of 0.025 mm, was left out of the pairs and meshed unlike its copy)."""
    import gmsh

    lo, hi = gmsh.model.getParametrizationBounds(1, curve)
    points = np.reshape(gmsh.model.getValue(1, curve, np.linspace(lo[0], hi[0], 5).tolist()), (-1, 3))
    return bool(np.all(np.abs(points[:, axis] - value) < tol))


