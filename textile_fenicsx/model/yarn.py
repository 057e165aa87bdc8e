"""A yarn: a C1 centreline through master nodes, repeated by the cell vectors, carrying sections.

The centreline is parametrised by s in [0, N-1] over N master nodes (segment i is s in [i, i+1],
local t = s - i), as TexGen does:
- "bezier": cubic Bezier per segment with control points P_i + T_i L/3 and P_{i+1} - T_{i+1} L/3,
  L = |P_{i+1} - P_i|, T the unit node tangent: the node's own tangent when it has one, else the
  normalised (next - previous) node (periodic neighbours taken across the repeat);
- "cubic": periodic (or natural) cubic spline through the nodes, per coordinate;
- "linear": straight segments.
A periodic yarn's last node is its first plus the period vector.
"""

from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import CubicSpline

from textile_fenicsx.common import limits
from textile_fenicsx.common.errors import TextileError
from textile_fenicsx.model.fibres import Fibres
from textile_fenicsx.model.yarn_sections import ConstantSection, NodeSections, PositionSections

__all__ = ["INTERPOLATIONS", "ConstantSection", "NodeSections", "PositionSections", "Yarn"]

INTERPOLATIONS = ("bezier", "cubic", "linear")


@dataclass(eq=False)
class Yarn:
    """A yarn of the textile (lengths in mm).

    nodes: (N, 3) master node positions. section: ConstantSection, NodeSections or PositionSections.
    repeats: (k, 3) vectors by which the yarn repeats (usually the cell's). tangents, ups: optional
    (N, 3) per-node tangent (zero rows: computed) and up vectors (zero rows: +z). angles: per-node
    section rotation about the tangent [rad]. fibres: optional fibre data (fibres.Fibres; a pair
    (count, diameter [mm]) is taken as such), for the fibre volume fraction.
    """

    nodes: np.ndarray
    section: ConstantSection | NodeSections | PositionSections
    interpolation: str = "bezier"
    periodic: bool = True
    repeats: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    tangents: np.ndarray | None = None
    ups: np.ndarray | None = None
    angles: np.ndarray | None = None
    force_in_plane_tangent: bool = False
    force_node_tangent_in_plane: bool = False
    fibres: Fibres | None = None
    name: str = ""

    def __post_init__(self):
        label = self.name or "yarn"
        self.nodes = np.array(self.nodes, dtype=float)
        if self.nodes.ndim != 2 or self.nodes.shape[1] != 3:
            raise TextileError(f"{label}: master nodes must be (N, 3) positions, got shape {self.nodes.shape}")
        if len(self.nodes) < 2:
            raise TextileError(f"{label}: needs at least 2 master nodes, got {len(self.nodes)}")
        if not np.all(np.isfinite(self.nodes)):
            raise TextileError(f"{label}: a master node position is not finite")
        limits.check_coordinates(f"{label}: master node positions", self.nodes)
        seg = np.linalg.norm(np.diff(self.nodes, axis=0), axis=1)
        if np.any(seg <= 1e-12):
            i = int(np.argmin(seg))
            raise TextileError(f"{label}: master nodes {i} and {i + 1} coincide")
        if self.interpolation not in INTERPOLATIONS:
            raise TextileError(f"{label}: interpolation must be one of {INTERPOLATIONS}, got {self.interpolation!r}")
        if not isinstance(self.section, (ConstantSection, NodeSections, PositionSections)):
            raise TextileError(f"{label}: section must be ConstantSection, NodeSections or PositionSections")
        if isinstance(self.section, NodeSections) and len(self.section.at_nodes) != len(self.nodes):
            raise TextileError(f"{label}: {len(self.section.at_nodes)} node sections for {len(self.nodes)} "
                               "master nodes")
        if isinstance(self.section, NodeSections):
            places = [(k, t) for k, t, _ in self.section.mid]
            if any(not (0 <= k < len(self.nodes) - 1 and 0 < t < 1) for k, t in places) \
                    or len(set(places)) != len(places):
                raise TextileError(f"{label}: a mid-segment section needs a segment 0..{len(self.nodes) - 2} "
                                   "and 0 < t < 1 (one section at each)")
        self.repeats = np.array(self.repeats, dtype=float).reshape(-1, 3)
        if not np.all(np.isfinite(self.repeats)):
            raise TextileError(f"{label}: a repeat vector is not finite")
        limits.check_many(f"{label}: repeat vectors", len(self.repeats), 3)
        limits.check_coordinates(f"{label}: repeat vectors", self.repeats)
        n = len(self.nodes)
        for attr, shape in (("tangents", (n, 3)), ("ups", (n, 3)), ("angles", (n,))):
            value = getattr(self, attr)
            if value is not None:
                value = np.array(value, dtype=float)
                if value.shape != shape or not np.all(np.isfinite(value)):
                    raise TextileError(f"{label}: {attr} must be finite with shape {shape}, got {value.shape}")
                setattr(self, attr, value)
        if isinstance(self.fibres, tuple) and len(self.fibres) == 2:
            try:
                self.fibres = Fibres(count=self.fibres[0], diameter=self.fibres[1])
            except TextileError as e:
                raise TextileError(f"{label}: {e}") from None
        if self.fibres is not None and not isinstance(self.fibres, Fibres):
            raise TextileError(f"{label}: fibres must be fibre data (Fibres), got {self.fibres!r:.60}")
        self._spline = None
        self._node_tangents = None

    def __repr__(self) -> str:
        """One line: name, master nodes, interpolation, period, sections."""
        shapes = sorted({type(x).__name__ for x in self.section.sections()})
        if isinstance(self.section, ConstantSection):
            x = self.section.section
            sections = f"{type(x).__name__} {x.width:g} x {x.height:g} mm"
        else:
            sections = f"{type(self.section).__name__} ({', '.join(shapes)})"
        p = self.period
        path = f"period ({p[0]:g}, {p[1]:g}, {p[2]:g}) mm" if self.periodic else "not periodic"
        return f"<Yarn {self.name!r}: {len(self.nodes)} master nodes, {self.interpolation}, {path}, {sections}>"

    # --- centreline -------------------------------------------------------------------------
    @property
    def period(self) -> np.ndarray:
        """The vector from the first to the last master node (the yarn's own repeat if periodic)."""
        return self.nodes[-1] - self.nodes[0]

    @property
    def n_segments(self) -> int:
        return len(self.nodes) - 1

    def node_tangents(self) -> np.ndarray:
        """Unit tangents at master nodes used by the Bezier interpolation (TexGen's rule)."""
        if self._node_tangents is None:
            self._node_tangents = _node_tangents(self.nodes, self.period, self.periodic, self.tangents,
                                                 self.force_node_tangent_in_plane)
        return self._node_tangents

    def _cubic(self):
        if self._spline is None:
            self._spline = _cubic_spline(self.nodes, self.period, self.periodic)
        return self._spline

    def _segment(self, s):
        s = np.clip(np.asarray(s, float), 0, self.n_segments)
        i = np.minimum(np.floor(s).astype(int), self.n_segments - 1)
        return i, s - i

    def centreline(self, s) -> tuple[np.ndarray, np.ndarray]:
        """Positions (M, 3) and unit tangents (M, 3) at parameters s (M,) in [0, N-1]."""
        i, t = self._segment(s)
        p0, p1 = self.nodes[i], self.nodes[i + 1]
        tt = t[:, None]
        if self.interpolation == "linear":
            pos, der = p0 + tt * (p1 - p0), p1 - p0
        elif self.interpolation == "bezier":
            T = self.node_tangents()
            third = np.linalg.norm(p1 - p0, axis=1, keepdims=True) / 3
            c1, c2 = p0 + T[i] * third, p1 - T[i + 1] * third
            m = 1 - tt
            pos = m**3 * p0 + 3 * m**2 * tt * c1 + 3 * m * tt**2 * c2 + tt**3 * p1
            der = 3 * m**2 * (c1 - p0) + 6 * m * tt * (c2 - c1) + 3 * tt**2 * (p1 - c2)
        else:
            spline, drift = self._cubic()
            ss = np.asarray(i + t, float)
            pos = spline(ss) + np.outer(ss, drift)
            der = spline(ss, 1) + drift
        if self.force_in_plane_tangent:
            der = der * np.array([1.0, 1.0, 0.0])
        norm = np.linalg.norm(der, axis=1, keepdims=True)
        return pos, der / np.where(norm > 0, norm, 1.0)

    def frames(self, s) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Positions, tangents, ups and sides (each (M, 3)) at parameters s: side = tangent x up."""
        pos, tan = self.centreline(s)
        i, t = self._segment(s)
        up, side = _up_and_side(tan, i, t, self.ups, self.angles, len(self.nodes), self.name or "yarn")
        return pos, tan, up, side

    def length_table(self, per_segment: int = 64) -> tuple[np.ndarray, np.ndarray]:
        """Dense parameters s and cumulative centreline length at them (for arc-length stations)."""
        s = np.linspace(0, self.n_segments, self.n_segments * per_segment + 1)
        pos, _ = self.centreline(s)
        return s, np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.diff(pos, axis=0), axis=1))))

    def length(self) -> float:
        """Centreline length over the master nodes [mm]."""
        return float(self.length_table()[1][-1])

    def stations(self, spacing: float, minimum_per_segment: int = 4, turn: float = np.inf) -> np.ndarray:
        """Parameters s of stations equispaced in arc length within each segment between master
        nodes (at most `spacing` mm apart, and a segment whose tangent turns by more than `turn`
        radians cut into that many more), the nodes and ends included. Per segment, so that a
        yarn continued over several periods (a coupon's) has the same stations in every period."""
        s, cum = self.length_table()
        per = (len(s) - 1) // self.n_segments
        at_nodes = cum[::per]
        counts = np.maximum(np.ceil(np.diff(at_nodes) / spacing).astype(int), minimum_per_segment)
        if np.isfinite(turn):
            _, tan = self.centreline(s)
            turning = np.arccos(np.clip(np.sum(tan[1:] * tan[:-1], axis=1), -1.0, 1.0)).reshape(-1, per).sum(axis=1)
            counts = np.maximum(counts, np.ceil(turning / turn).astype(int))
        targets = np.concatenate([np.linspace(a, b, n, endpoint=False) for a, b, n in
                                  zip(at_nodes[:-1], at_nodes[1:], counts)] + [at_nodes[-1:]])
        return np.interp(targets, cum, s)

    # --- sections ---------------------------------------------------------------------------
    def section_points(self, s, n_points: int) -> np.ndarray:
        """Section polygons (M, n_points, 2) in (side, up) coordinates at parameters s."""
        i, t = self._segment(s)
        return self.section.points_along(self.nodes, i, t, n_points)

    def tube(self, spacing: float, n_points: int, per_segment: int = 4) -> tuple[np.ndarray, np.ndarray]:
        """The yarn's surface over its master nodes as a structured grid.

        Returns (vertices (M, n_points, 3), stations s (M,)): vertex [m, k] is section point k at
        station m. For a periodic yarn the last station repeats the first, shifted by the period.
        """
        s = self.stations(spacing, per_segment)
        return self.section_polygons(s, n_points), s

    def section_polygons(self, s, n_points: int, scale: float = 1.0) -> np.ndarray:
        """Section polygons (M, n_points, 3) [mm] at parameters s, each scaled about its centreline
        point by `scale`."""
        pos, _, up, side = self.frames(s)
        sec = self.section_points(s, n_points) * scale
        return pos[:, None, :] + sec[..., :1] * side[:, None, :] + sec[..., 1:] * up[:, None, :]


def _cubic_spline(nodes: np.ndarray, period: np.ndarray, periodic: bool) -> tuple[CubicSpline, np.ndarray]:
    """The "cubic" centreline through the nodes (N, 3) at s = 0..N-1 and its drift per unit of s: a
    periodic spline of the nodes less a linear drift of `period` along s, or a natural spline
    (no drift)."""
    s = np.arange(len(nodes), dtype=float)
    if periodic:
        drift = np.outer(s / s[-1], period)  # periodic part plus a linear drift
        part = nodes - drift
        part[-1] = part[0]  # the last node is the first plus the period: equal, not to round-off
        return CubicSpline(s, part, bc_type="periodic"), period / s[-1]
    return CubicSpline(s, nodes, bc_type="natural"), np.zeros(3)


def _node_tangents(p: np.ndarray, period: np.ndarray, periodic: bool, tangents: np.ndarray | None,
                   in_plane: bool) -> np.ndarray:
    """Unit tangents at the master nodes p (N, 3) by TexGen's rule: the normalised (next - previous)
    node (periodic neighbours taken across the repeat `period`), a node's own tangent where its row
    of `tangents` is not zero, with no z component where `in_plane`."""
    prev = np.vstack((p[-2] - period if periodic else p[0], p[:-1]))
    nxt = np.vstack((p[1:], p[1] + period if periodic else p[-1]))
    t = nxt - prev
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    if tangents is not None:
        own = np.linalg.norm(tangents, axis=1) > 0
        t[own] = tangents[own]
    if in_plane:
        t[:, 2] = 0.0
    return t


def _up_and_side(tan: np.ndarray, i: np.ndarray, t: np.ndarray, ups: np.ndarray | None, angles: np.ndarray | None,
                 n_nodes: int, label: str) -> tuple[np.ndarray, np.ndarray]:
    """The sections' up and side unit vectors (M, 3) at centreline points of unit tangents `tan` in
    segments i at local t: the master nodes' up vectors (None or zero rows: +z) interpolated along
    the segment and made normal to the tangent, side = tangent x up; both turned about the tangent
    by the nodes' angles [rad], interpolated likewise."""
    ups = np.tile([0.0, 0.0, 1.0], (n_nodes, 1)) if ups is None else ups.copy()
    ups[np.linalg.norm(ups, axis=1) == 0] = (0.0, 0.0, 1.0)
    up = ups[i] + (ups[i + 1] - ups[i]) * t[:, None]
    up -= np.sum(up * tan, axis=1, keepdims=True) * tan
    norm = np.linalg.norm(up, axis=1, keepdims=True)
    if np.any(norm < 1e-9):
        raise TextileError(f"{label}: its up vector is parallel to its tangent")
    up /= norm
    side = np.cross(tan, up)
    if angles is not None and np.any(angles):
        a = (angles[i] + (angles[i + 1] - angles[i]) * t)[:, None]
        up, side = up * np.cos(a) - side * np.sin(a), side * np.cos(a) + up * np.sin(a)
    return up, side
