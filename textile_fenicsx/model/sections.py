"""Yarn cross-sections, with TexGen's meaning of width, height, power and distortion.

A section is a closed curve in the section plane, in coordinates (s, u): u along the yarn's up
vector, s along side = tangent x up (for a yarn along +x with up +z, s points to -y). Every section
is sampled anticlockwise in (s, u) starting at its +s extreme (TexGen's t = 0), so sections of one
yarn can be blended point by point. `Hybrid` is TexGen's CSectionHybrid: pieces of other sections,
each over a range of t between its divisions (TexGen's refine of an orthogonal weave gives its outer
wefts a power-ellipse half and a `Flat` half).
"""

from dataclasses import dataclass, field
from math import gamma, pi, sqrt

import numpy as np

from textile_fenicsx.common.errors import TextileError
from textile_fenicsx.common.limits import (
    MAX_POLYGON_POINTS,
    MAX_POWER,
    MAX_SECTION,
    MIN_POWER,
    check_length,
    check_range,
)


class Section:
    """Base class: subclasses define `curve(t)` for t in [0, 1) and their exact `area()`."""

    width: float
    height: float

    def curve(self, t: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def points(self, n: int) -> np.ndarray:
        """n points (n, 2) anticlockwise from t = 0, uniform in TexGen's parameter t."""
        return self.curve(np.arange(n) / n)

    def area(self) -> float:
        raise NotImplementedError


@dataclass(frozen=True)
class Ellipse(Section):
    """Ellipse of full width and height [mm]: s = w/2 cos(2 pi t), u = h/2 sin(2 pi t)."""

    width: float
    height: float

    def __post_init__(self):
        check_length("ellipse width", self.width, MAX_SECTION)
        check_length("ellipse height", self.height, MAX_SECTION)

    def curve(self, t):
        a = 2 * pi * np.asarray(t, float)
        return np.column_stack((0.5 * self.width * np.cos(a), 0.5 * self.height * np.sin(a)))

    def area(self):
        return pi * self.width * self.height / 4


@dataclass(frozen=True)
class PowerEllipse(Section):
    """TexGen's power ellipse [mm]: s = w/2 cos(2 pi t), u = h/2 sin(2 pi t)^power for t <= 1/2 and
    -h/2 (-sin(2 pi t))^power after (TexGen's CSectionPowerEllipse::GetPoint, 0^0 = 1 as in C).

    power < 1 squares the section off (towards a rectangle), power > 1 sharpens it; power 0 is the
    w x h rectangle itself (TexGen's refine of an orthogonal weave writes it), its first point the
    top right corner; x_offset moves the top and bottom extremes sideways (TexGen's XOffset, mm).
    """

    width: float
    height: float
    power: float
    x_offset: float = 0.0

    def __post_init__(self):
        check_length("power-ellipse width", self.width, MAX_SECTION)
        check_length("power-ellipse height", self.height, MAX_SECTION)
        check_range("power-ellipse power", self.power, MIN_POWER, MAX_POWER)
        if not np.isfinite(self.x_offset) or abs(self.x_offset) >= 0.5 * self.width:
            raise TextileError(f"power-ellipse x_offset must lie within +-width/2, got {self.x_offset!r}")

    def curve(self, t):
        t = np.asarray(t, float)
        a = 2 * pi * t
        right = (t <= 0.25) | (t >= 0.75)
        half_w = np.where(right, 0.5 * self.width - self.x_offset, 0.5 * self.width + self.x_offset)
        s = half_w * np.cos(a) + self.x_offset
        sin = np.sin(a)
        upper = t <= 0.5
        u = 0.5 * self.height * np.where(upper, np.maximum(sin, 0.0), np.maximum(-sin, 0.0)) ** self.power
        return np.column_stack((s, np.where(upper, u, -u)))

    def area(self):
        # 4 * (w/2)(h/2) * int_0^{pi/2} sin^(p+1): the x_offset shears halves without changing area.
        p = self.power
        return self.width * self.height * sqrt(pi) / 2 * gamma(p / 2 + 1) / gamma(p / 2 + 1.5)


@dataclass(frozen=True)
class Lenticular(Section):
    """Two circular arcs meeting at the sides [mm]; distortion moves the corners up by that much.

    The upper arc has sagitta (height - 2 distortion)/2, the lower (height + 2 distortion)/2.
    """

    width: float
    height: float
    distortion: float = 0.0

    def __post_init__(self):
        check_length("lenticular width", self.width, MAX_SECTION)
        check_length("lenticular height", self.height, MAX_SECTION)
        if not np.isfinite(self.distortion) or abs(self.distortion) >= 0.5 * self.height:
            raise TextileError(f"lenticular distortion must lie within +-height/2, got {self.distortion!r}")

    def _arc(self, sagitta2):  # radius and centre offset of an arc with full chord width, 2*sagitta
        radius = (self.width**2 + sagitta2**2) / (4 * sagitta2)
        return radius, radius - 0.5 * self.height

    def curve(self, t):
        t = np.asarray(t, float)
        out = np.empty((len(t), 2))
        top = t < 0.5
        for mask, dh, sign, angle in (
            (top, self.height - 2 * self.distortion, 1.0, lambda t: (1 - 4 * t)),
            (~top, self.height + 2 * self.distortion, -1.0, lambda t: (-3 + 4 * t)),
        ):
            radius, offset = self._arc(dh)
            theta = angle(t[mask]) * np.arcsin(0.5 * self.width / radius)
            out[mask, 0] = radius * np.sin(theta)
            out[mask, 1] = sign * (radius * np.cos(theta) - offset)
        return out

    def area(self):
        total = 0.0
        for dh in (self.height - 2 * self.distortion, self.height + 2 * self.distortion):
            s = dh / 2
            r = (self.width**2 + dh**2) / (4 * dh)
            total += r * r * np.arccos((r - s) / r) - (r - s) * sqrt(2 * r * s - s * s)
        return float(total)


@dataclass(frozen=True)
class Polygon(Section):
    """A polygon of (s, u) vertices [mm], anticlockwise, starting where blending should start."""

    vertices: tuple = field(default=())

    def __post_init__(self):
        n = len(self.vertices) if hasattr(self.vertices, "__len__") else 0
        if n > MAX_POLYGON_POINTS:
            raise TextileError(f"polygon section has {n} points, more than the limit of {MAX_POLYGON_POINTS}")
        v = np.asarray(self.vertices, float)
        if v.ndim != 2 or v.shape[1] != 2 or len(v) < 3:
            raise TextileError(f"polygon section needs at least 3 (s, u) points, got shape {v.shape}")
        if not np.all(np.isfinite(v)):
            raise TextileError("polygon section has a non-finite coordinate")
        if np.max(np.abs(v)) > MAX_SECTION:
            raise TextileError(f"polygon section has a point {np.max(np.abs(v)):g} mm from the yarn's centre, beyond "
                               f"the limit of {MAX_SECTION:g} mm")
        if _signed_area(v) <= 0:
            raise TextileError("polygon section must run anticlockwise in (s, u) and enclose an area")
        object.__setattr__(self, "vertices", tuple(map(tuple, v)))

    def __reduce__(self):
        """Pickled as one array of its vertices and rebuilt as __post_init__ leaves them (numpy
        floats pickled one by one took 0.08 s of the CLI's time for a corrected satin4 at seed
        0.25, whose model goes to the figures' process)."""
        return _polygon, (np.asarray(self.vertices, float),)

    @property
    def width(self) -> float:  # type: ignore[override]  # derived from the vertices, not a field
        v = np.asarray(self.vertices)
        return float(np.ptp(v[:, 0]))

    @property
    def height(self) -> float:  # type: ignore[override]  # derived from the vertices, not a field
        v = np.asarray(self.vertices)
        return float(np.ptp(v[:, 1]))

    def points(self, n: int) -> np.ndarray:
        """The vertices themselves when n is their count (a corrected yarn's sections are sampled
        back exactly: resampling by perimeter cuts corners, -1 % of area on power ellipses), else n
        points uniform in perimeter."""
        v = np.asarray(self.vertices)
        return v.copy() if n == len(v) else self.curve(np.arange(n) / n)

    def curve(self, t):
        """Points at fraction t of the perimeter from the first vertex."""
        v = np.asarray(self.vertices)
        closed = np.vstack((v, v[:1]))
        seg = np.linalg.norm(np.diff(closed, axis=0), axis=1)
        cum = np.concatenate(([0.0], np.cumsum(seg)))
        arc = np.asarray(t, float) % 1.0 * cum[-1]
        return np.column_stack((np.interp(arc, cum, closed[:, 0]), np.interp(arc, cum, closed[:, 1])))

    def area(self):
        return float(_signed_area(np.asarray(self.vertices)))


def _polygon(vertices: np.ndarray) -> Polygon:
    """A pickled Polygon back (Polygon.__reduce__): its vertices (n, 2) as the tuples of numpy
    floats __post_init__ made of them, without checking them again."""
    polygon = object.__new__(Polygon)
    object.__setattr__(polygon, "vertices", tuple(map(tuple, vertices)))
    return polygon


@dataclass(frozen=True)
class Flat(Section):
    """A section of no height [mm]: s = w/2 cos(2 pi t), u = 0, i.e. the segment between (+-w/2, 0)
    run twice. TexGen writes it as an ellipse of height 0: the flat half of a weft that its refine
    of an orthogonal weave halves (a `Hybrid` piece). It encloses nothing, so it is only ever a
    piece of a hybrid section (the readers refuse it as a yarn's own section)."""

    width: float

    def __post_init__(self):
        check_length("flat section width", self.width, MAX_SECTION)

    @property
    def height(self) -> float:  # type: ignore[override]  # no height: not a field
        return 0.0

    def curve(self, t):
        a = 2 * pi * np.asarray(t, float)
        return np.column_stack((0.5 * self.width * np.cos(a), np.zeros_like(a)))

    def area(self):
        return 0.0


# Points per piece that a hybrid section's extents and area are measured with: the area of a
# power-ellipse half (power 0.6) comes within 2e-6 of its exact value.
HYBRID_SAMPLES = 4096
# Hybrids inside hybrids: TexGen allows any depth; more than this is taken for a broken file.
MAX_HYBRID_DEPTH = 4


@dataclass(frozen=True)
class Hybrid(Section):
    """TexGen's CSectionHybrid [mm]: a section made of pieces of others.

    divisions: fractions of TexGen's parameter t, increasing, in [0, 1]; pieces: one section per
    division. Piece k gives the points with divisions[k] < t <= divisions[k + 1], the last one those
    after the last division and up to the first (round t = 0), each the point of the piece's own
    curve at that same t (TexGen's CSectionHybrid::GetPoint). E.g. divisions (0, 0.5) with pieces
    (Flat(w), PowerEllipse(w, h, p)): a flat top over a power-ellipse bottom, as TexGen's refine
    writes the bottom wefts of an orthogonal weave. Where neighbouring pieces do not meet, the
    section's polygon joins them with a straight edge.
    """

    divisions: tuple = ()
    pieces: tuple = ()

    def __post_init__(self):
        d = np.asarray(self.divisions, float)
        if d.ndim != 1 or len(d) == 0 or len(d) != len(self.pieces):
            raise TextileError(f"hybrid section needs one piece per division, at least one; got {len(d)} "
                               f"divisions and {len(self.pieces)} pieces")
        if len(d) > MAX_POLYGON_POINTS:
            raise TextileError(f"hybrid section has {len(d)} divisions, more than the limit of {MAX_POLYGON_POINTS}")
        if not np.all(np.isfinite(d)) or np.any(d < 0) or np.any(d > 1) or np.any(np.diff(d) < 0):
            raise TextileError(f"hybrid section divisions must increase from 0 to 1, got {self.divisions}")
        if not all(isinstance(p, Section) for p in self.pieces):
            raise TextileError("hybrid section pieces must be sections")
        if _depth(self) > MAX_HYBRID_DEPTH:
            raise TextileError(f"hybrid sections nested more than {MAX_HYBRID_DEPTH} deep")
        object.__setattr__(self, "divisions", tuple(float(x) for x in d))
        object.__setattr__(self, "pieces", tuple(self.pieces))
        if _signed_area(self._dense()) <= 0:
            raise TextileError(f"hybrid section (divisions {self.divisions}, pieces "
                               f"{', '.join(type(p).__name__ for p in self.pieces)}) must run anticlockwise "
                               "in (s, u) and enclose an area")

    def piece_of(self, t: np.ndarray) -> np.ndarray:
        """Index of the piece that gives the point at each t."""
        k = np.searchsorted(np.asarray(self.divisions), np.asarray(t, float), side="left") - 1
        return np.where(k < 0, len(self.divisions) - 1, k)

    def curve(self, t):
        t = np.asarray(t, float)
        k = self.piece_of(t)
        out = np.empty((len(t), 2))
        for j, piece in enumerate(self.pieces):
            mask = k == j
            if np.any(mask):
                out[mask] = piece.curve(t[mask])
        return out

    def _dense(self) -> np.ndarray:
        """The curve at HYBRID_SAMPLES points per piece and at every division (both pieces' ends)."""
        t = np.concatenate((np.arange(HYBRID_SAMPLES * len(self.pieces)) / (HYBRID_SAMPLES * len(self.pieces)),
                            self.divisions, np.nextafter(np.asarray(self.divisions), 2.0)))
        return self.curve(np.unique(t[t < 1.0]))

    @property
    def width(self) -> float:  # type: ignore[override]  # derived from the pieces, not a field
        return float(np.ptp(self._dense()[:, 0]))

    @property
    def height(self) -> float:  # type: ignore[override]  # derived from the pieces, not a field
        return float(np.ptp(self._dense()[:, 1]))

    def area(self):
        return float(_signed_area(self._dense()))


def _depth(section: Section) -> int:
    """How deep hybrid sections nest in this one (0 for any other section)."""
    if not isinstance(section, Hybrid):
        return 0
    return 1 + max((_depth(p) for p in section.pieces), default=0)


def _signed_area(v: np.ndarray) -> float:
    x, y = v[:, 0], v[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def polygon_area(points: np.ndarray) -> float:
    """Signed area of a closed polygon given by its vertices (n, 2), positive when anticlockwise."""
    return _signed_area(np.asarray(points, float))


def polygon_centroids(polys: np.ndarray) -> np.ndarray:
    """Centroids (S, 2) of the polygons (S, n, 2), of their areas, not of their points; (0, 0), the
    section plane's origin (the path), for a polygon with no area (shrunk to a point or a line)."""
    u, v = polys[..., 0], polys[..., 1]
    un, vn = np.roll(u, -1, axis=1), np.roll(v, -1, axis=1)
    cross = u * vn - un * v
    six_area = 3.0 * np.sum(cross, axis=1)
    extent = np.maximum(np.ptp(u, axis=1), np.ptp(v, axis=1))
    flat = ~(np.abs(six_area) > 1e-12 * extent**2)
    c = np.column_stack((np.sum((u + un) * cross, axis=1), np.sum((v + vn) * cross, axis=1)))
    return np.where(flat[:, None], 0.0, c / np.where(flat, 1.0, six_area)[:, None])


def blend(p1: np.ndarray, p2: np.ndarray, u, ramped: bool = False, polar: bool = False) -> np.ndarray:
    """Blend two sampled sections point by point (TexGen's interpolated yarn sections).

    u in [0, 1] (scalar or per-station array broadcast against the points); ramped uses the
    smoothstep 3u^2 - 2u^3; polar blends radius and angle instead of s and u.
    """
    u = np.asarray(u, float)[..., None, None] if np.ndim(u) else float(u)
    if ramped:
        u = 3 * u * u - 2 * u * u * u
    if not polar:
        return p1 + (p2 - p1) * u
    r1, r2 = np.linalg.norm(p1, axis=-1), np.linalg.norm(p2, axis=-1)
    a1, a2 = np.arctan2(p1[..., 1], p1[..., 0]), np.arctan2(p2[..., 1], p2[..., 0])
    a2 = np.where(a2 - a1 > pi, a2 - 2 * pi, np.where(a1 - a2 > pi, a2 + 2 * pi, a2))
    uu = u[..., 0] if np.ndim(u) else u
    r, a = r1 + (r2 - r1) * uu, a1 + (a2 - a1) * uu
    return np.stack((r * np.cos(a), r * np.sin(a)), axis=-1)
