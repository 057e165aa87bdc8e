"""The voxel mesh's default sizes, one per axis, and how finely a grid resolves the yarns (issue 72).

A voxel's phase is read at its centre, so a voxel mesh places each yarn's surface to within half a
voxel: its yarn volumes, and with them the cell's stiffness, move with the grid's phase against the
yarns as the voxels shrink (the staircase error). The default sizes follow a rule on the yarns'
own sizes, each yarn's height and width being the median over its stations of its section's extent
along the section's up and side axes:

- through the thickness, ACROSS_HEIGHT voxels across the thinnest yarn's height;
- in plan, along x and y alike, ACROSS_WIDTH voxels across the narrowest yarn's width (the width
  sets the error in plan: a section's edges are sampled at the voxels' centres);

the voxels at most these sizes (the counts rounded up). Where that grid would have more than
DEFAULT_MAX_VOXELS voxels (a 3D weave's thin binders, a cell of many yarns), the three sizes grow by
one factor until it fits. Of the grids a few percent finer than that one, voxel.default_grid then
takes the first whose voxels hold the model's yarn fraction (union_fraction) within 0.25 %: the
grid's phase against the yarns moves their volume by whole percent. A grid coarser than the rule,
asked or capped, is reported with a warning that names the yarn and the error measured at that
resolution (EXPECTED_ERROR). The rule and the errors are measured in docs/volume.md, "Voxel sizes"
(bench/voxel_rule.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from textile_fenicsx.model.textile import Textile
from textile_fenicsx.volume.box import Box

ACROSS_HEIGHT = 8  # voxels across the thinnest yarn's height
ACROSS_WIDTH = 12  # voxels across the narrowest yarn's width, along x and along y
# The default's largest grid: 60 000 voxels are 1.45 M second-order unknowns, about 9.4 GB of
# homogenising on one rank (memory.HOMOGENISE_BYTES_PER_DOF).
DEFAULT_MAX_VOXELS = 60_000
# The worst error [%] of Ex, Ez and Gxy against the converged value on the plain weave, the 2/2
# twill and the 4-harness satin (reference/models) on grids with a fraction r of the rule's voxels
# across the yarns along every axis, finest first, never less than at a finer r (docs/volume.md,
# "Voxel sizes"): the defaults 1.3 % (r 1); r 0.75 7.4 % (the twill's Gxy, its grid's yarn fraction
# 4.7 % off the model's), r 0.5 5.8 % (the satin's Ez), r 0.25 18.6 % (the satin's Ez)
EXPECTED_ERROR = ((1.0, 2.0), (0.75, 7.5), (0.5, 7.5), (0.25, 19.0))

# The scatter of a voxel mesh's moduli about their trend as it is refined [-]: grids a few percent
# apart sample the yarns' surfaces at different points. At the default grid, with its yarn fraction
# held within 0.25 %, Ex, Ez and Gxy of the plain weave, the 2/2 twill and the 4-harness satin were
# within 1.3 % of converged, and the plain weave's Ez moved by -0.6 % from 27 to 40 voxels across
# after +0.06 % from 18 (docs/volume.md, "Voxel sizes"): the error estimate of a voxel mesh's
# properties is at least 1.5 % of each (volume/refinement.py).
SCATTER = 0.015

Sizes = tuple[float, float, float]


def yarn_sizes(textile: Textile, n_points: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Each yarn's width and height [mm]: the median, over stations along it at most the model's
    resolution spacing apart, of its section's extent along the section's side and up axes (the
    median, not the least: a corrected yarn pinched at one crossing keeps its height)."""
    widths, heights = [], []
    for y in textile.yarns:
        sec = y.section_points(y.stations(textile.resolution.spacing, 1), n_points)
        widths.append(float(np.median(np.ptp(sec[..., 0], axis=1))))
        heights.append(float(np.median(np.ptp(sec[..., 1], axis=1))))
    return np.array(widths), np.array(heights)


@dataclass(frozen=True)
class VoxelRule:
    """A model's yarn sizes and the default voxel sizes they give (default_sizes).

    names, widths, heights: each yarn's name, width and height [mm]. rule: the rule's sizes (hx, hy,
    hz) [mm]; sizes: the default's (the rule's, or coarser where capped: DEFAULT_MAX_VOXELS).
    """

    names: tuple[str, ...]
    widths: np.ndarray
    heights: np.ndarray
    rule: Sizes
    sizes: Sizes

    def across(self, voxel: Sizes) -> tuple[np.ndarray, np.ndarray]:
        """Voxels across each yarn's height (along z) and width (the coarser of the sizes in plan)."""
        return self.heights / voxel[2], self.widths / max(voxel[0], voxel[1])

    def fraction(self, voxel: Sizes) -> float:
        """The least fraction of the rule's voxels across a yarn's height or width that a grid of
        these voxel sizes [mm] has (1 where it meets the rule everywhere)."""
        high, wide = self.across(voxel)
        return float(min(1.0, high.min() / ACROSS_HEIGHT, wide.min() / ACROSS_WIDTH))

    def report(self, voxel: Sizes) -> dict[str, Any]:
        """The rule, its sizes and how a grid of these voxel sizes [mm] resolves the yarns (JSON-ready)."""
        high, wide = self.across(voxel)
        i, j = int(np.argmin(high)), int(np.argmin(wide))
        r = self.fraction(voxel)
        return {"rule": f"{ACROSS_HEIGHT} voxels across the thinnest yarn's height, {ACROSS_WIDTH} across the "
                        f"narrowest yarn's width (at most {DEFAULT_MAX_VOXELS} voxels by default)",
                "rule_mm": list(self.rule), "default_mm": list(self.sizes), "capped": self.sizes != self.rule,
                "thinnest": {"yarn": self.names[i], "height_mm": float(self.heights[i]),
                             "voxels_across": float(high[i])},
                "narrowest": {"yarn": self.names[j], "width_mm": float(self.widths[j]),
                              "voxels_across": float(wide[j])},
                "fraction_of_rule": r, "expected_error_percent": expected_error(r)}

    def short(self, voxel: Sizes, default: bool = False) -> str:
        """What a grid of these voxel sizes [mm] misses of the rule and the error to expect (a
        warning's text), or '' where it meets the rule; default: the grid is the default one."""
        r = self.fraction(voxel)
        if r >= 1 - 1e-9:
            return ""
        high, wide = self.across(voxel)
        i, j = int(np.argmin(high)), int(np.argmin(wide))
        misses = []
        if high[i] < ACROSS_HEIGHT * (1 - 1e-9):
            misses.append(f"{self.names[i]} is {high[i]:.1f} voxels across its height of {self.heights[i]:.3g} mm "
                          f"(the rule: {ACROSS_HEIGHT})")
        if wide[j] < ACROSS_WIDTH * (1 - 1e-9):
            misses.append(f"{self.names[j]} is {wide[j]:.1f} voxels across its width of {self.widths[j]:.3g} mm "
                          f"(the rule: {ACROSS_WIDTH})")
        why = (f"the default rule's grid would have more than {DEFAULT_MAX_VOXELS} voxels, so the default is coarser: "
               if default and self.sizes != self.rule else "")
        return (f"{why}{'; '.join(misses)}: expect Ex, Ez and Gxy off by up to about {expected_error(r):.0f} % "
                f"(measured, docs/volume.md); give a smaller --size, e.g. {_sizes_text(self.rule)}")


def expected_error(fraction: float) -> float:
    """The worst error [%] of Ex, Ez and Gxy measured on grids with this fraction of the rule's
    voxels across the yarns (EXPECTED_ERROR, interpolated; its coarsest beyond)."""
    r, e = np.array(EXPECTED_ERROR).T
    return float(np.interp(fraction, r[::-1], e[::-1]))


def _sizes_text(sizes: Sizes) -> str:
    return " ".join(f"{h:.3g}" for h in sizes)


def union_fraction(textile: Textile, box: Box, n: int = 400) -> float:
    """The yarns' share of the box [-], measured on the model: the union of the yarns' vertical-ray
    intervals within the box over an n x n grid of the cell (overlaps counted once)."""
    xy, area = textile.cell.grid(n)
    c = textile.columns(xy)
    bottom, top = np.clip(c.bottom, box.lo[2], box.hi[2]), np.clip(c.top, box.lo[2], box.hi[2])
    order = np.lexsort((bottom, c.point))
    point, bottom, top = c.point[order], bottom[order], top[order]
    offset = point * (10 * (float(np.abs(top).max(initial=0.0)) + 1))  # keeps each column's running top its own
    reach = np.maximum.accumulate(top + offset)
    before = np.r_[-np.inf, reach[:-1]] - offset
    before[np.r_[True, point[1:] != point[:-1]]] = -np.inf  # a column's first interval
    return float(np.sum(np.maximum(0.0, top - np.maximum(bottom, before))) * area / box.volume)


def default_sizes(textile: Textile, box: Box) -> VoxelRule:
    """The default voxel sizes of the textile's cell `box` (module docstring): the rule's, each an
    exact part of the box's side at most that size, scaled up by one factor where the grid would
    have more than DEFAULT_MAX_VOXELS voxels."""
    widths, heights = yarn_sizes(textile)
    plan = float(widths.min()) / ACROSS_WIDTH
    wanted = np.array([plan, plan, float(heights.min()) / ACROSS_HEIGHT])
    counts = np.maximum(np.ceil(box.size / wanted - 1e-9), 1)
    rule = tuple(float(v) for v in box.size / counts)
    scale = 1.0
    while np.prod(counts) > DEFAULT_MAX_VOXELS:  # all three sizes 1 % larger a step
        scale *= 1.01
        counts = np.maximum(np.ceil(box.size / (wanted * scale) - 1e-9), 1)
    sizes = tuple(float(v) for v in box.size / counts)
    return VoxelRule(tuple(y.name for y in textile.yarns), widths, heights, rule, sizes)  # type: ignore[arg-type]
