"""Builders of idealised unit cells: 2D weaves from a pattern matrix and 3D orthogonal weaves.

Conventions (mm): the cell is [0, Lx] x [0, Ly]; warp yarns run along x, weft yarns along y.
A 2D weave sheared by an angle (`shear`, degrees; docs/shear.md) keeps its warps along x and turns
its wefts to (sin, cos) of the angle, as TexGen's CShearedTextileWeave2D: the spacings stay measured
along the yarns (a pin-jointed net), the cell is [0, Lx] x [0, Ly cos] with its rows shifted by
Ly sin along x (Cell.shift).
A 2D weave pattern P has one row per warp and one column per weft: P[i][j] = 1 when warp i passes
over weft j. At a crossing the lower yarn's centre sits at its half height above z = 0 and the upper
yarn's at the fabric thickness minus its half height; between crossings the paths are Bezier curves
with in-plane tangents at the crossings, as TexGen's 2D weave builds them. The cell's z range is
the fabric's padded by 5 % of its thickness on each side (TexGen's default domain).
"""

from math import gcd

import numpy as np

from textile_fenicsx.common.errors import TextileError, check_positive
from textile_fenicsx.common.limits import MAX_PATTERN, MAX_SECTION, MAX_SIZE, check_count, check_length
from textile_fenicsx.model.sections import Ellipse, PowerEllipse
from textile_fenicsx.model.textile import Cell, Textile
from textile_fenicsx.model.yarn import ConstantSection, Yarn

# --- patterns -------------------------------------------------------------------------------

def plain() -> np.ndarray:
    """Plain weave: warp over, under, alternately."""
    return np.array([[1, 0], [0, 1]])


def twill(over: int = 2, under: int = 2) -> np.ndarray:
    """over/under twill: each warp floats over `over` wefts, under `under`, shifting by one."""
    over, under = check_count("twill over", over, 1, MAX_PATTERN), check_count("twill under", under, 1, MAX_PATTERN)
    if over < 1 or under < 1:
        raise TextileError(f"twill needs over >= 1 and under >= 1, got {over}/{under}")
    n = over + under
    i, j = np.indices((n, n))
    return ((j - i) % n < over).astype(int)


def satin(harness: int = 5, move: int = 2) -> np.ndarray:
    """Warp-faced n-harness satin: warp i goes under weft (i * move) mod harness only."""
    harness = check_count("satin harness", harness, 1, MAX_PATTERN)
    move = check_count("satin move", move, 1, MAX_PATTERN)
    if harness < 5 or not (1 < move < harness - 1) or gcd(harness, move) != 1:
        raise TextileError(f"satin needs harness >= 5 and 1 < move < harness - 1 coprime with it, "
                           f"got harness={harness}, move={move} (4-harness: crowfoot_satin())")
    P = np.ones((harness, harness), int)
    P[np.arange(harness), (np.arange(harness) * move) % harness] = 0
    return P


def crowfoot_satin() -> np.ndarray:
    """4-harness crowfoot satin: warp under weft at (0, 0), (1, 1), (2, 3), (3, 2)."""
    P = np.ones((4, 4), int)
    for i, j in ((0, 0), (1, 1), (2, 3), (3, 2)):
        P[i, j] = 0
    return P


PATTERNS = {"plain": plain, "twill": twill, "satin": satin, "crowfoot_satin": crowfoot_satin}


def check_pattern(pattern) -> np.ndarray:
    """A validated 0/1 pattern matrix; every warp and weft must interlace (go both over and under)."""
    try:
        P = np.array(pattern, dtype=float)
    except (TypeError, ValueError):
        raise TextileError("weave pattern must be a rectangular matrix of 0 and 1") from None
    if P.ndim != 2 or P.size == 0:
        raise TextileError(f"weave pattern must be a non-empty rectangular matrix, got shape {P.shape}")
    if max(P.shape) > MAX_PATTERN:
        raise TextileError(f"weave pattern: {P.shape[0]} x {P.shape[1]} is larger than the limit of {MAX_PATTERN} "
                           "warps or wefts")
    if not np.all((P == 0) | (P == 1)):
        raise TextileError("weave pattern entries must be 0 (weft over) or 1 (warp over)")
    for i, row in enumerate(P):
        if row.min() == row.max():
            raise TextileError(f"weave pattern: warp {i} never interlaces (always {'over' if row[0] else 'under'})")
    for j, col in enumerate(P.T):
        if col.min() == col.max():
            raise TextileError(f"weave pattern: weft {j} never interlaces (always {'under' if col[0] else 'over'})")
    return P.astype(int)


def _per_yarn(name: str, value, n: int) -> np.ndarray:
    v = np.broadcast_to(np.asarray(value, float), (n,)) if np.ndim(value) == 0 else np.asarray(value, float)
    if v.shape != (n,):
        raise TextileError(f"{name}: expected one value or {n} values, got {len(v)}")
    for k, x in enumerate(v):
        check_length(f"{name}[{k}]", x, MAX_SECTION if "spacing" not in name else MAX_SIZE)
    return v.copy()


def _section(width, height, power):
    return Ellipse(width, height) if power is None or power == 1.0 else PowerEllipse(width, height, power)


def _check_fit(kind: str, widths, spacings, allow_overlap: bool):
    if allow_overlap:
        return
    for k, (w, s) in enumerate(zip(widths, spacings)):
        if w > s:
            raise TextileError(f"{kind} {k}: width {w:g} mm is larger than its spacing {s:g} mm "
                               "(neighbours would overlap; allow it with allow_overlap = true / --allow-overlap)")


def jamming_angle(widths, spacings) -> float:
    """The shear angle [degrees] at which yarns of these widths at these spacings (along the other
    yarns) jam: sheared by g, neighbours stand spacing cos g apart across their length, so the
    widest yarn for its spacing meets its neighbour at acos(width / spacing)."""
    ratio = float(np.max(np.asarray(widths, float) / np.asarray(spacings, float)))
    return float(np.degrees(np.arccos(min(ratio, 1.0))))


def _check_shear(shear, widths: dict, spacings: dict, allow_overlap: bool) -> float:
    """The shear angle [degrees] checked: finite, below 90 degrees in size, and below the angle at
    which the yarns jam (unless overlaps are allowed)."""
    try:
        g = float(shear)
    except (TypeError, ValueError):
        raise TextileError(f"shear angle must be a number of degrees, got {shear!r}") from None
    if not np.isfinite(g) or abs(g) >= 90.0:
        raise TextileError(f"shear angle must be between -90 and 90 degrees, got {shear!r}")
    if allow_overlap or g == 0.0:
        return g
    jam = {kind: jamming_angle(widths[kind], spacings[kind]) for kind in widths}
    kind = min(jam, key=lambda k: jam[k])
    if abs(g) >= jam[kind]:
        k = int(np.argmax(widths[kind] / spacings[kind]))
        raise TextileError(f"a shear of {abs(g):g} degrees jams the yarns: they jam at {jam[kind]:.2f} degrees, where "
                           f"{kind} {k} (width {widths[kind][k]:g} mm, spacing {spacings[kind][k]:g} mm) meets its "
                           f"neighbour (spacing x cos(shear) = width); give narrower yarns (--set width=W) or a "
                           "smaller shear")
    return g


def weave2d(pattern, spacing=2.0, width=1.8, height=0.3, thickness=None, *, weft_spacing=None,
            weft_width=None, weft_height=None, power=None, allow_overlap: bool = False,
            shear: float = 0.0, name: str = "weave2d") -> Textile:
    """A 2D weave from a pattern matrix.

    spacing, width, height: warp values [mm], one for all or one per warp; weft_* default to them.
    thickness: fabric thickness [mm] (default: warp + weft height). power: section power (None:
    ellipse). allow_overlap: accept widths larger than spacings. shear: the angle [degrees] the
    wefts turn from y toward x (the module's conventions); refused at or beyond the yarns' jamming
    angle (`jamming_angle`).
    """
    P = check_pattern(pattern)
    n_warp, n_weft = P.shape
    sy = _per_yarn("warp spacing", spacing, n_warp)
    wy = _per_yarn("warp width", width, n_warp)
    hy = _per_yarn("warp height", height, n_warp)
    sx = _per_yarn("weft spacing", spacing if weft_spacing is None else weft_spacing, n_weft)
    wx = _per_yarn("weft width", width if weft_width is None else weft_width, n_weft)
    hx = _per_yarn("weft height", height if weft_height is None else weft_height, n_weft)
    if power is not None:
        check_positive("section power", power)
    _check_fit("warp", wy, sy, allow_overlap)
    _check_fit("weft", wx, sx, allow_overlap)
    g = np.radians(_check_shear(shear, {"warp": wy, "weft": wx}, {"warp": sy, "weft": sx}, allow_overlap))
    sin, cos = (np.sin(g), np.cos(g)) if g else (0.0, 1.0)  # exactly the unsheared weave at 0
    T = float(np.max(hy) + np.max(hx)) if thickness is None else check_length("fabric thickness", thickness)
    if T < max(hy.max(), hx.max()):
        raise TextileError(f"fabric thickness {T:g} mm is less than the tallest yarn")
    Lx, Ly = float(sx.sum()), float(sy.sum())
    x = np.cumsum(sx) - sx / 2  # weft positions along x
    y = np.cumsum(sy) - sy / 2  # warp positions along y
    yarns = []
    flat = np.array([1.0, 0.0, 0.0])
    cell = Cell(Lx, Ly * cos, z_range=(-0.05 * T, 1.05 * T), shift=Ly * sin)
    for i in range(n_warp):
        z = np.where(P[i] == 1, T - hy[i] / 2, hy[i] / 2)
        nodes = np.column_stack((x + y[i] * sin, np.full(n_weft, y[i] * cos), z))
        nodes = np.vstack((nodes, nodes[0] + (Lx, 0, 0)))
        yarns.append(Yarn(nodes, ConstantSection(_section(wy[i], hy[i], power)), "bezier",
                          repeats=cell.repeats, tangents=np.tile(flat, (n_weft + 1, 1)), name=f"warp {i}"))
    along_y = np.array([sin, cos, 0.0])
    for j in range(n_weft):
        z = np.where(P[:, j] == 1, hx[j] / 2, T - hx[j] / 2)
        nodes = np.column_stack((x[j] + y * sin, y * cos, z))
        nodes = np.vstack((nodes, nodes[0] + cell.repeats[1]))
        yarns.append(Yarn(nodes, ConstantSection(_section(wx[j], hx[j], power)), "bezier",
                          repeats=cell.repeats, tangents=np.tile(along_y, (n_warp + 1, 1)), name=f"weft {j}"))
    return Textile(cell, yarns, name=name)


def orthogonal(n_warp_stacks: int = 2, n_weft_columns: int = 4, warp_layers: int = 2, *,
               warp_spacing=3.8, warp_width=3.6, warp_height=0.35, warp_power=0.6,
               weft_spacing=2.8, weft_width=2.2, weft_height=0.3, weft_power=0.6,
               binder_spacing=1.4, binder_width=1.2, binder_height=0.16, binder_power=0.8,
               binder_pattern=None, allow_overlap: bool = False, name: str = "orthogonal") -> Textile:
    """A 3D orthogonal weave.

    Along y the cell holds n_warp_stacks warp stacks, each followed by a binder (so Ly =
    n_warp_stacks * (warp_spacing + binder_spacing)); along x, n_weft_columns weft columns at
    weft_spacing. Through the thickness, weft and warp layers alternate, wefts outermost
    (warp_layers + 1 weft layers). A binder runs along x over the top weft layer or under the bottom
    one at each weft column (binder_pattern[b][j] = 1: over), passing through the thickness in the
    gap between weft columns. Sizes in mm; powers are the power-ellipse sections' powers.
    """
    n_warp_stacks, n_weft_columns, warp_layers = (
        check_count(f"orthogonal: {label}", v, 1, MAX_PATTERN) for label, v in
        (("n_warp_stacks", n_warp_stacks), ("n_weft_columns", n_weft_columns), ("warp_layers", warp_layers)))
    if n_weft_columns < 2:
        raise TextileError("orthogonal: needs at least 2 weft columns for binders to interlace")
    for label, v in (("warp_spacing", warp_spacing), ("warp_width", warp_width), ("warp_height", warp_height),
                     ("warp_power", warp_power), ("weft_spacing", weft_spacing), ("weft_width", weft_width),
                     ("weft_height", weft_height), ("weft_power", weft_power), ("binder_spacing", binder_spacing),
                     ("binder_width", binder_width), ("binder_height", binder_height),
                     ("binder_power", binder_power)):
        check_positive(f"orthogonal: {label}", v)
        if not label.endswith("power"):
            check_length(f"orthogonal: {label}", v, MAX_SECTION if "spacing" not in label else MAX_SIZE)
    _check_fit("warp", [warp_width], [warp_spacing], allow_overlap)
    _check_fit("weft", [weft_width], [weft_spacing], allow_overlap)
    _check_fit("binder", [binder_width], [binder_spacing], allow_overlap)
    if binder_pattern is None:
        binder_pattern = [[(j + b) % 2 == 0 for j in range(n_weft_columns)] for b in range(n_warp_stacks)]
    B = np.array(binder_pattern, dtype=float)
    if B.shape != (n_warp_stacks, n_weft_columns) or not np.all((B == 0) | (B == 1)):
        raise TextileError(f"orthogonal: binder_pattern must be a {n_warp_stacks} x {n_weft_columns} matrix of 0/1")
    gap = weft_spacing - weft_width
    if gap < binder_height and not allow_overlap:
        raise TextileError(f"orthogonal: the gap between weft columns ({gap:g} mm) is narrower than the "
                           f"binder height ({binder_height:g} mm): binders cannot pass between wefts")

    Lx = n_weft_columns * weft_spacing
    Ly = n_warp_stacks * (warp_spacing + binder_spacing)
    repeats = np.array([(Lx, 0, 0), (0, Ly, 0)])
    x = (np.arange(n_weft_columns) + 0.5) * weft_spacing
    # z levels: weft, warp, weft, ..., weft (bottom to top)
    heights = [weft_height if k % 2 == 0 else warp_height for k in range(2 * warp_layers + 1)]
    tops = np.cumsum(heights)
    centres = tops - np.asarray(heights) / 2
    along_x, along_y = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    warp_sec = PowerEllipse(warp_width, warp_height, warp_power)
    weft_sec = PowerEllipse(weft_width, weft_height, weft_power)
    binder_sec = PowerEllipse(binder_width, binder_height, binder_power)

    yarns = []
    for s in range(n_warp_stacks):
        y_warp = s * (warp_spacing + binder_spacing) + warp_spacing / 2
        for layer in range(warp_layers):
            z = centres[2 * layer + 1]
            nodes = np.array([[0.0, y_warp, z], [Lx / 2, y_warp, z], [Lx, y_warp, z]])
            yarns.append(Yarn(nodes, ConstantSection(warp_sec), "bezier", repeats=repeats,
                              tangents=np.tile(along_x, (3, 1)), name=f"warp {s}.{layer}"))
        y_b = (s + 1) * (warp_spacing + binder_spacing) - binder_spacing / 2
        z_over, z_under = tops[-1] + binder_height / 2, -binder_height / 2
        z_hi, z_lo = centres[-1], centres[0]
        path: list[tuple] = []
        tangents: list[np.ndarray] = []
        for j in range(n_weft_columns):
            over = B[s, j] == 1
            path.append((x[j], y_b, z_over if over else z_under))
            tangents.append(along_x)
            nxt = B[s, (j + 1) % n_weft_columns] == 1
            if nxt != over:  # through the thickness in the gap after column j
                xm = x[j] + weft_spacing / 2
                half = max(gap - binder_height, 0.0) / 2
                zs = (z_hi, z_lo) if over else (z_lo, z_hi)
                path += [(xm - half, y_b, zs[0]), (xm + half, y_b, zs[1])]
                tangents += [np.zeros(3), np.zeros(3)]
        path.append((path[0][0] + Lx, y_b, path[0][2]))
        tangents.append(along_x)
        yarns.append(Yarn(np.array(path), ConstantSection(binder_sec), "bezier", repeats=repeats,
                          tangents=np.array(tangents), name=f"binder {s}"))
    for j in range(n_weft_columns):
        for layer in range(warp_layers + 1):
            z = centres[2 * layer]
            nodes = np.array([[x[j], 0.0, z], [x[j], Ly / 2, z], [x[j], Ly, z]])
            yarns.append(Yarn(nodes, ConstantSection(weft_sec), "bezier", repeats=repeats,
                              tangents=np.tile(along_y, (3, 1)), name=f"weft {j}.{layer}"))
    thickness = tops[-1] + 2 * binder_height
    pad = 0.05 * thickness
    return Textile(Cell(Lx, Ly, z_range=(-binder_height - pad, tops[-1] + binder_height + pad)), yarns, name=name,
                   thickness=thickness)


def build(name: str, **options) -> Textile:
    """A named weave: plain, twill, satin, crowfoot_satin (2D) or orthogonal (3D), with options."""
    if name == "orthogonal":
        return orthogonal(**options)
    if name not in PATTERNS:
        raise TextileError(f"unknown weave {name!r}; choose from {sorted(PATTERNS) + ['orthogonal']}")
    pattern_args = {k: options.pop(k) for k in ("over", "under", "harness", "move") if k in options}
    try:
        pattern = PATTERNS[name](**pattern_args)
    except TypeError as e:
        raise TextileError(f"weave {name!r}: {e}") from None
    return weave2d(pattern, name=name, **options)
