"""Bounds on every size, count and resolution that a model file, the command line or the API may
ask for (docs/errors.md). A value outside them is refused with a TextileError
naming the field, before anything is built from it: an absurd size or count must end in a message,
not in a gmsh abort or the kernel killing the process for memory.

The bounds are wide for textile unit cells in mm (yarns 0.1-20 mm wide, cells up to a few tens of
mm, coupons of up to 100 x 100 cells) and narrow enough that nothing inside them can exhaust the
machine before the memory estimate of the mesh (meshes/projected.py, check_memory) is made.
"""

import math

from textile_fenicsx.common.errors import FormatError, TextileError

# Lengths [mm]
MIN_LENGTH = 1e-3          # 1 micrometre: any size, spacing, seed or resolution
MAX_SECTION = 100.0        # a yarn section's width or height
MAX_SIZE = 1_000.0         # a spacing, a fabric thickness, a mesh seed, a resolution spacing
MAX_CELL = 10_000.0        # a cell side (a coupon of 100 x 100 cells of 100 mm)
MAX_COORDINATE = 100_000.0  # |x|, |y|, |z| of a master node, a cell origin, a repeat vector
# Other numbers
MIN_POWER, MAX_POWER = 0.0, 100.0  # a power-ellipse's power (0: TexGen's rectangle, which its refine writes)
# Counts
MAX_YARNS = 1_000                  # yarns in a model
MAX_NODES_PER_YARN = 2_000         # master nodes of one yarn (TexGen's have 3-50; corrected ones one per station)
MAX_NODES = 100_000                # master nodes of a model
MAX_POLYGON_POINTS = 4_096         # vertices of a polygon section
MIN_SECTION_POINTS, MAX_SECTION_POINTS = 8, 4_096  # points per section of the yarn surfaces
MAX_SURFACE_POINTS = 30_000_000    # points of all yarn surfaces (stations x section points), ~4 GB of triangles
MAX_PATTERN = 100                  # a weave pattern's warps or wefts; harness, over, under, layers, stacks, columns
MAX_REPEATS = 100                  # coupon repeats along x or y
MAX_SHEAR_RATIO = 3.7320508075688772  # a sheared cell's |shift| / ly: tan 75 degrees (beyond, a degenerate lattice)
MAX_GRID = 1_000                   # rays per cell side of the metrics (200 is the reference; 1000: ~30 s)
MAX_ITERATIONS = 10_000            # contact iterations
MAX_MEMORY_GB = 1e6                # a --memory-limit
MAX_SLOPE = 1e6                    # a max_slope
MAX_FILE_BYTES = 200 * 2**20       # a model file (a .tg3 of 1e5 master nodes is about 20 MB)


def _number(name: str, value) -> float:
    if isinstance(value, bool):
        raise TextileError(f"{name} must be a number, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError, OverflowError):
        raise TextileError(f"{name} must be a number, got {value!r:.60}") from None
    if not math.isfinite(v):
        raise TextileError(f"{name} must be finite, got {value!r}")
    return v


def check_length(name: str, value, largest: float = MAX_SIZE, smallest: float = MIN_LENGTH) -> float:
    """value [mm] as a float, if it is a number from `smallest` to `largest`; else TextileError."""
    v = _number(name, value)
    if v <= 0:
        raise TextileError(f"{name} must be > 0, got {value!r}")
    if v < smallest:
        raise TextileError(f"{name} must be at least {smallest:g} mm, got {value!r}")
    if v > largest:
        raise TextileError(f"{name} must be at most {largest:g} mm, got {value!r}")
    return v


def check_range(name: str, value, smallest: float, largest: float, unit: str = "") -> float:
    """value as a float, if it is a number from `smallest` to `largest`; else TextileError."""
    v = _number(name, value)
    if not smallest <= v <= largest:
        raise TextileError(f"{name} must be from {smallest:g} to {largest:g}{unit}, got {value!r}")
    return v


def check_count(name: str, value, smallest: int, largest: int) -> int:
    """value as an int, if it is a whole number from `smallest` to `largest`; else TextileError."""
    if isinstance(value, bool):
        raise TextileError(f"{name} must be a whole number, got {value!r}")
    try:
        whole = float(value) == int(value)
    except (TypeError, ValueError, OverflowError):
        raise TextileError(f"{name} must be a whole number, got {value!r:.60}") from None
    if not whole:
        raise TextileError(f"{name} must be a whole number, got {value!r}")
    if not smallest <= int(value) <= largest:
        raise TextileError(f"{name} must be a whole number from {smallest} to {largest}, got {value!r}")
    return int(value)


def check_many(name: str, n: int, largest: int, error=TextileError) -> None:
    """Refuse more than `largest` items of something (counted before they are built)."""
    if n > largest:
        raise error(f"{name}: {n} is more than the limit of {largest}")


def check_coordinates(name: str, values) -> None:
    """Every coordinate within +-MAX_COORDINATE mm (values: an array of numbers, finite)."""
    import numpy as np

    values = np.asarray(values, float)
    if values.size and np.max(np.abs(values)) > MAX_COORDINATE:
        raise TextileError(f"{name}: a coordinate of {np.max(np.abs(values)):g} mm is beyond the limit of "
                           f"+-{MAX_COORDINATE:g} mm")


def check_file_size(path) -> None:
    """Refuse a model file larger than MAX_FILE_BYTES before reading it (FormatError)."""
    import os

    try:
        size = os.stat(path).st_size
    except OSError:
        return  # the reader says why it cannot read it
    if size > MAX_FILE_BYTES:
        raise FormatError(f"{path}: {size / 2**20:.0f} MB is more than the limit of {MAX_FILE_BYTES // 2**20} MB "
                           "for a model file")
