"""The project's error types: every bad input ends in one of these, with the culprit named."""


class TextileError(ValueError):
    """A textile model, file or parameter that cannot be used; the message names the culprit."""


class FormatError(TextileError):
    """A malformed, truncated or unsupported input file (.tg3, TOML, JSON)."""


class GeometryError(TextileError):
    """Geometry the method cannot handle (too steep, no stacking order, empty footprint...)."""


class SolverError(RuntimeError):
    """A linear or nonlinear solve did not converge, or gave a non-finite answer."""


class UnresolvedError(SolverError):
    """A direct solve that failed (singular, or negative on the eigenvalue nearest zero) where the
    interior point's weights had outgrown what the factor resolves of the plates: a near-null mode
    of a mesh too coarse for the weave (a jammed corner), which a finer mesh may mend."""


class MeshError(RuntimeError):
    """A mesher that failed on input it accepted (gmsh's own error): the run failed, not the input."""


class OutputError(RuntimeError):
    """An output folder that cannot be written now (another run is writing it)."""


def check_positive(name: str, value, allow_zero: bool = False) -> float:
    """Return value as a float if it is finite and > 0 (>= 0 with allow_zero); else raise TextileError."""
    try:
        v = float(value)
    except (TypeError, ValueError, OverflowError):
        raise TextileError(f"{name} must be a number, got {value!r}") from None
    if not (v == v) or v in (float("inf"), float("-inf")):
        raise TextileError(f"{name} must be finite, got {value!r}")
    if v < 0 or (v == 0 and not allow_zero):
        raise TextileError(f"{name} must be {'>= 0' if allow_zero else '> 0'}, got {value!r}")
    return v
