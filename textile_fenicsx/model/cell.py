"""The unit cell in plan (`Cell`: origin, sizes, periodic or cut) and how finely yarn surfaces are
discretised (`Resolution`), in mm. textile.py re-exports both."""

from dataclasses import dataclass

import numpy as np

from textile_fenicsx.common import limits
from textile_fenicsx.common.errors import TextileError

__all__ = ["Cell", "Resolution"]


@dataclass(frozen=True)
class Cell:
    """The unit cell [x0, x0 + lx] x [y0, y0 + ly] in mm; z_range (zmin, zmax) clips if given.
    periodic: the cell repeats (its opposite sides are the same points); False for a coupon with
    free edges, whose sides are the yarns' cut ends.
    shift [mm]: the lattice of a sheared cell (docs/shear.md). The cell repeats by a1 = (lx, 0) and
    a2 = (shift, ly): the point (x, y) is the point (x + shift, y + ly), so the rectangle is still a
    whole cell (a fundamental domain of the lattice), its x sides pair as before and its y sides
    pair with a move of `shift` along x. 0 for an unsheared cell; the shear angle is
    atan(shift / ly)."""

    lx: float
    ly: float
    x0: float = 0.0
    y0: float = 0.0
    z_range: tuple | None = None
    periodic: bool = True
    shift: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "lx", limits.check_length("cell size lx", self.lx, limits.MAX_CELL))
        object.__setattr__(self, "ly", limits.check_length("cell size ly", self.ly, limits.MAX_CELL))
        for name in ("x0", "y0"):
            value = getattr(self, name)
            try:
                value = float(value)
            except (TypeError, ValueError, OverflowError):
                raise TextileError(f"cell origin {name} must be a number, got {value!r}") from None
            if not np.isfinite(value):
                raise TextileError(f"cell origin {name} must be finite, got {getattr(self, name)!r}")
            limits.check_coordinates(f"cell origin {name}", value)
            object.__setattr__(self, name, value)
        if self.z_range is not None:
            lo, hi = map(float, self.z_range)
            if not (np.isfinite(lo) and np.isfinite(hi) and hi > lo):
                raise TextileError(f"cell z_range must be finite with zmax > zmin, got {self.z_range!r}")
            limits.check_coordinates("cell z_range", (lo, hi))
            object.__setattr__(self, "z_range", (lo, hi))
        if not isinstance(self.periodic, (bool, np.bool_)):
            raise TextileError(f"cell periodic must be true or false, got {self.periodic!r}")
        object.__setattr__(self, "periodic", bool(self.periodic))
        try:
            shift = float(self.shift)
        except (TypeError, ValueError, OverflowError):
            raise TextileError(f"cell shift must be a number, got {self.shift!r}") from None
        if not np.isfinite(shift):
            raise TextileError(f"cell shift must be finite, got {self.shift!r}")
        if shift != 0.0 and not self.periodic:
            raise TextileError("cell shift: a cell with free edges has no lattice to shear")
        if abs(shift) > limits.MAX_SHEAR_RATIO * self.ly:  # also refuses a lattice that has degenerated
            raise TextileError(f"cell shift {shift:g} mm over a height of {self.ly:g} mm: a shear of "
                               f"{np.degrees(np.arctan2(abs(shift), self.ly)):.1f} degrees, beyond the "
                               f"{np.degrees(np.arctan(limits.MAX_SHEAR_RATIO)):.0f} degrees a lattice may have "
                               "(a degenerate lattice)")
        object.__setattr__(self, "shift", shift + 0.0)  # no -0.0

    @property
    def sheared(self) -> bool:
        """Whether the y sides pair with a move along x (shift != 0)."""
        return self.shift != 0.0

    @property
    def shear_angle(self) -> float:
        """The angle [degrees] between a2 = (shift, ly) and y: 0 for an unsheared cell."""
        return float(np.degrees(np.arctan2(self.shift, self.ly)))

    @property
    def repeats(self) -> np.ndarray:
        """The lattice vectors a1 = (lx, 0, 0) and a2 = (shift, ly, 0) [mm]."""
        return np.array([[self.lx, 0.0, 0.0], [self.shift, self.ly, 0.0]])

    def lattice_coordinates(self, d: np.ndarray) -> np.ndarray:
        """In-plane vectors d (N, 2) [mm] in units of the lattice vectors: d = a a1 + b a2 -> (a, b)."""
        d = np.asarray(d, float).reshape(-1, 2)
        b = d[:, 1] / self.ly
        return np.column_stack(((d[:, 0] - b * self.shift) / self.lx, b))

    def translation(self, a: np.ndarray | float, b: np.ndarray | float) -> np.ndarray:
        """The in-plane lattice translations a a1 + b a2 (N, 2) [mm] for whole numbers a, b."""
        a, b = np.broadcast_arrays(np.asarray(a, float), np.asarray(b, float))
        return np.column_stack(((a * self.lx + b * self.shift).ravel(), (b * self.ly).ravel()))

    def nearest_translation(self, d: np.ndarray) -> np.ndarray:
        """The lattice translations (N, 2) nearest the in-plane vectors d (N, 2) in lattice units:
        the y row first, then along x (exact for d a translation plus less than half a cell)."""
        d = np.asarray(d, float).reshape(-1, 2)
        b = np.round(d[:, 1] / self.ly)
        return self.translation(np.round((d[:, 0] - b * self.shift) / self.lx), b)

    def neighbours(self) -> np.ndarray:
        """The 9 in-plane translations (9, 2) [mm] to the cell itself (first) and the 8 cells around
        it: the rows above and below are moved by the whole cells along x that bring them back over
        the cell (their x offset within half a cell), so the copies surround the cell also when
        shifted."""
        rows = np.array([0.0, -1.0, 1.0])
        back = -np.round(rows * self.shift / self.lx)
        a = np.concatenate([back[k] + rows for k in range(3)])
        b = np.repeat(rows, 3)
        return self.translation(a, b)

    @property
    def area(self) -> float:
        return self.lx * self.ly

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        return self.x0, self.x0 + self.lx, self.y0, self.y0 + self.ly

    def wrap(self, points: np.ndarray) -> np.ndarray:
        """Points (N, 2) or (N, 3) [mm] brought into the cell in plan (z kept): by whole cells where
        it is periodic, onto its nearest side where it is not (a yarn's stretch beyond a coupon's cut
        end then takes what is found at the end)."""
        p = np.array(points, float)
        x0, x1, y0, y1 = self.bounds
        if self.periodic:
            rows = np.floor((p[:, 1] - y0) / self.ly)  # a sheared cell: a row up is shift along x
            x = p[:, 0] - rows * self.shift if self.shift else p[:, 0]
            p[:, 0], p[:, 1] = x0 + np.mod(x - x0, self.lx), y0 + np.mod(p[:, 1] - y0, self.ly)
        else:
            p[:, 0], p[:, 1] = np.clip(p[:, 0], x0, x1), np.clip(p[:, 1], y0, y1)
        return p

    def grid(self, n: int) -> tuple[np.ndarray, float]:
        """Cell-centred n x n sample points (n*n, 2) and the area each represents."""
        x = self.x0 + (np.arange(n) + 0.5) * self.lx / n
        y = self.y0 + (np.arange(n) + 0.5) * self.ly / n
        X, Y = np.meshgrid(x, y, indexing="ij")
        return np.column_stack((X.ravel(), Y.ravel())), self.area / n**2


@dataclass(frozen=True)
class Resolution:
    """How finely yarn surfaces are discretised: station spacing along the yarn [mm], points
    per section polygon (64 points: section area within 0.16 % of the smooth curve) and the fewest
    stations between two master nodes (1 for a corrected yarn, whose master nodes are stations)."""

    spacing: float = 0.1
    section_points: int = 64
    per_segment: int = 4

    def __post_init__(self) -> None:
        limits.check_length("resolution spacing", self.spacing)
        limits.check_count("resolution section_points", self.section_points, limits.MIN_SECTION_POINTS,
                           limits.MAX_SECTION_POINTS)
        limits.check_count("resolution per_segment", self.per_segment, 1, 64)
