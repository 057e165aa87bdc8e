"""PETSc options as a plain dict under a prefix, in PETSc's global database only while read.

    ksp.setOptionsPrefix(prefix)
    with petsc_options(prefix, {"ksp_type": "cg", "pc_type": "gamg"}):
        ksp.setFromOptions()
        ksp.setUp()

writes each key under the prefix and deletes each key it wrote when the block ends, also on an
error, so that no option outlives the object that read it nor reaches the next one. Where the
options are read over more than one call (MUMPS reads its ICNTL at the first factorisation), keep
the returned object and `close()` it after the last read.
"""

from collections.abc import Mapping
from types import TracebackType

from petsc4py import PETSc


class PetscOptions:
    """Options written under a prefix on creation, deleted by `close()` (once) or a `with` block."""

    def __init__(self, prefix: str, options: Mapping[str, object]) -> None:
        self.prefix = prefix
        self._keys = list(options)
        database = PETSc.Options()
        for key, value in options.items():
            database[prefix + key] = value

    def close(self) -> None:
        """Delete the keys written; closing again does nothing."""
        database = PETSc.Options()
        for key in self._keys:
            database.delValue(self.prefix + key)
        self._keys = []

    def __enter__(self) -> "PetscOptions":
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        self.close()


def petsc_options(prefix: str, options: Mapping[str, object]) -> PetscOptions:
    """`options` written under `prefix` in PETSc.Options() until the result is closed or its
    `with` block ends."""
    return PetscOptions(prefix, options)
