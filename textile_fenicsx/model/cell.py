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
    free edges, whose sides are the yarns' cut ends."""

    lx: float
    ly: float
    x0: float = 0.0
    y0: float = 0.0
    z_range: tuple | None = None
    periodic: bool = True

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

    @property
    def repeats(self) -> np.ndarray:
        return np.array([[self.lx, 0.0, 0.0], [0.0, self.ly, 0.0]])

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
            p[:, 0], p[:, 1] = x0 + np.mod(p[:, 0] - x0, self.lx), y0 + np.mod(p[:, 1] - y0, self.ly)
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
