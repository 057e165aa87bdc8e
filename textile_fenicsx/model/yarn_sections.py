"""How a yarn's section varies along it: the same all along (`ConstantSection`), one per master node
blended between them (`NodeSections`, TexGen's InterpNode), or at fractions of its length
(`PositionSections`, TexGen's InterpPosition). Each gives its section polygons at points along
the yarn (`points_along`); the shapes themselves are in sections.py.
"""

from dataclasses import dataclass

import numpy as np

from textile_fenicsx.common import limits
from textile_fenicsx.common.errors import TextileError
from textile_fenicsx.model.sections import Section, blend

__all__ = ["ConstantSection", "NodeSections", "PositionSections"]


@dataclass(frozen=True)
class ConstantSection:
    """The same section all along the yarn."""

    section: Section

    def sections(self) -> tuple[Section, ...]:
        return (self.section,)

    def points_along(self, nodes: np.ndarray, i: np.ndarray, t: np.ndarray, n_points: int) -> np.ndarray:
        """Section polygons (M, n_points, 2) at local parameters t in segments i."""
        return np.broadcast_to(self.section.points(n_points), (len(i), n_points, 2)).copy()


@dataclass(frozen=True)
class NodeSections:
    """One section per master node, blended point by point between nodes (TexGen InterpNode).
    mid: sections inside segments, ((segment k, t in (0, 1), section), ...), as TexGen's refine
    writes them (MidNodeSection; one or more per segment): within segment k the blend runs from node
    k through its mid-sections in order of t to node k + 1 (TexGen's GetSectionsToInterp)."""

    at_nodes: tuple
    ramped: bool = False
    polar: bool = False
    mid: tuple = ()

    def __post_init__(self) -> None:
        order = sorted(range(len(self.mid)), key=lambda m: (self.mid[m][0], self.mid[m][1]))
        object.__setattr__(self, "mid", tuple(self.mid[m] for m in order))

    def sections(self) -> tuple[Section, ...]:
        return tuple(self.at_nodes) + tuple(m[2] for m in self.mid)

    def points_along(self, nodes: np.ndarray, i: np.ndarray, t: np.ndarray, n_points: int) -> np.ndarray:
        """Section polygons (M, n_points, 2) at local parameters t in segments i."""
        pts = np.array([x.points(n_points) for x in self.sections()])
        out = blend(pts[i], pts[i + 1], t, self.ramped, self.polar)
        first = len(self.at_nodes)
        for k in sorted({m[0] for m in self.mid}):  # node k -> its mids in order -> node k + 1
            mids = [m for m in range(len(self.mid)) if self.mid[m][0] == k]
            stops = np.array([0.0] + [self.mid[m][1] for m in mids] + [1.0])
            shapes = [pts[k]] + [pts[first + m] for m in mids] + [pts[k + 1]]
            for j in range(len(stops) - 1):
                here = (i == k) & (t > stops[j]) & (t <= stops[j + 1]) if j else (i == k) & (t <= stops[1])
                if np.any(here):
                    u = (t[here] - stops[j]) / (stops[j + 1] - stops[j])
                    out[here] = blend(shapes[j][None], shapes[j + 1][None], u, self.ramped, self.polar)
        return out


@dataclass(frozen=True)
class PositionSections:
    """Sections at fractions of the yarn's length in [0, 1), blended between (TexGen InterpPosition)."""

    positions: tuple
    at_positions: tuple
    ramped: bool = False
    polar: bool = False

    def __post_init__(self) -> None:
        if len(self.positions) != len(self.at_positions) or not self.positions:
            raise TextileError("position sections need as many positions as sections, at least one")
        limits.check_many("position sections", len(self.positions), limits.MAX_NODES_PER_YARN)
        p = np.asarray(self.positions, float)
        if np.any(~np.isfinite(p)) or np.any(np.diff(p) < 0):
            raise TextileError(f"section positions must be finite and increasing, got {self.positions}")

    def sections(self) -> tuple[Section, ...]:
        return tuple(self.at_positions)

    def points_along(self, nodes: np.ndarray, i: np.ndarray, t: np.ndarray, n_points: int) -> np.ndarray:
        """Section polygons (M, n_points, 2) at local parameters t in segments i of the yarn
        through `nodes`. Positions are fractions of the yarn's length measured along straight
        segments (TexGen)."""
        pts = np.array([x.points(n_points) for x in self.sections()])
        seg = np.linalg.norm(np.diff(nodes, axis=0), axis=1)
        cum = np.concatenate(([0.0], np.cumsum(seg)))
        frac = (cum[i] + t * seg[i]) / cum[-1]
        pos = np.asarray(self.positions, float)
        ext_pos = np.concatenate(([pos[-1] - 1], pos, [pos[0] + 1]))
        ext_pts = np.concatenate((pts[-1:], pts, pts[:1]))
        j = np.clip(np.searchsorted(ext_pos, frac, side="right") - 1, 0, len(ext_pos) - 2)
        span = ext_pos[j + 1] - ext_pos[j]
        u = np.where(span > 0, (frac - ext_pos[j]) / np.where(span > 0, span, 1), 0.0)
        return blend(ext_pts[j], ext_pts[j + 1], u, self.ramped, self.polar)
