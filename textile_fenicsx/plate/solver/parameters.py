"""What the solve takes and what it gives: plate stiffnesses, iteration settings, the solution."""

from dataclasses import dataclass, field

import numpy as np

import dolfinx
from textile_fenicsx.common.errors import TextileError, check_positive
from textile_fenicsx.common.limits import MAX_ITERATIONS, check_count
from textile_fenicsx.common.memory import BYTES_PER_DOF, BYTES_PER_DOF_OUT_OF_CORE
from textile_fenicsx.model.fibres import HEXAGONAL
from textile_fenicsx.plate.solver.linear import DIRECT_LDLT, OUT_OF_CORE

__all__ = ["METHODS", "Compaction", "Mould", "PlateParameters", "Solution", "SolverOptions"]

METHODS = ("exact", "penalty")


@dataclass(frozen=True)
class PlateParameters:
    """Stiffnesses of the yarn plates (TexGen's defaults, which the paper used).

    Db1, Db2: bending stiffness along and across the fibre [N mm]; Db12: twisting stiffness [N mm]
    (default (Db1 + Db2) / 4); sigma1: fibre tension [N/mm]; Ec: contact stiffness where yarns
    penetrate [N/mm^3] (the penalty method's; the exact method needs none); Et: stiffness of the
    spring that holds yarns together where they are apart [N/mm^3]; alpha: interior-penalty
    factor [-]. Only ratios matter for the geometry.
    """

    Db1: float = 1.0
    Db2: float = 1.0
    Db12: float | None = None
    sigma1: float = 1.0
    Ec: float = 1e3
    Et: float = 1e-4
    alpha: float = 3.0

    def __post_init__(self):
        for name in ("Db1", "Db2", "sigma1", "Et"):
            check_positive(name, getattr(self, name), allow_zero=True)
        check_positive("Ec", self.Ec)
        check_positive("alpha", self.alpha)
        if self.Db12 is None:
            object.__setattr__(self, "Db12", (self.Db1 + self.Db2) / 4)
        check_positive("Db12", self.Db12, allow_zero=True)


@dataclass(frozen=True)
class Compaction:
    """The yarns' transverse compaction (DESIGN.md 5, forms/compression.py): each yarn's thickness is
    an unknown beside its height, held by Van Wyk's law p = k E_f (phi^3 - phi0^3) with the width kept
    (phi = phi0 t0 / t).

    modulus: k E_f [N/mm^2 = MPa]. phi0: each yarn's relaxed intra-yarn fibre fraction [-] (one
    number for all, or one per plate yarn). phi_max: the maximum packing [-] no yarn may exceed
    (default: the hexagonal packing of equal circles, pi / (2 sqrt 3) = 0.9069).
    """

    modulus: float
    phi0: float | tuple[float, ...] = 0.65
    phi_max: float = HEXAGONAL

    def __post_init__(self):
        check_positive("compaction modulus", self.modulus)
        check_positive("maximum packing", self.phi_max)
        if self.phi_max >= 1:
            raise TextileError(f"maximum packing must be below 1, got {self.phi_max:g}")
        for phi in np.atleast_1d(self.phi0):
            if not 0 < phi < self.phi_max:
                raise TextileError(f"a yarn's relaxed fibre fraction must lie between 0 and the maximum packing "
                                   f"{self.phi_max:.4g}, got {phi:g}")

    def fraction(self, yarn: int) -> float:
        """The relaxed fibre fraction phi0 of plate yarn `yarn` [-]."""
        return float(self.phi0) if isinstance(self.phi0, (int, float)) else float(self.phi0[yarn])


@dataclass(frozen=True)
class Mould:
    """Two rigid platens, z = bottom and z = top [mm], that no yarn's surface may cross: a mould
    cavity of thickness top - bottom (DESIGN.md 5, the mould)."""

    bottom: float
    top: float

    def __post_init__(self):
        if not (np.isfinite(self.bottom) and np.isfinite(self.top) and self.top > self.bottom):
            raise TextileError(f"mould: the top platen (z = {self.top}) must lie above the bottom one "
                               f"(z = {self.bottom})")

    @property
    def thickness(self) -> float:
        return self.top - self.bottom


@dataclass(frozen=True)
class SolverOptions:
    """How to iterate.

    method: "exact" (default: no penetration at the mesh nodes, to penetration_tol [mm], whatever
    the stiffnesses) or "penalty" (the paper's: contact stiffness Ec, penetration ~ load / Ec).
    max_iterations: cap on Newton steps. Exact method: penetration_tol [mm], the largest
    penetration left at a node; displacement_tol [mm], the largest move of the last step (the
    distance to the exact minimiser is of that order). petsc: options of the linear solves (a
    plain dict, written under the solver's own prefix only while it is read). out_of_core: MUMPS
    keeps its factors on disk (OUT_OF_CORE, in $MUMPS_OOC_TMPDIR or /tmp), for coupons larger than
    the memory: the memory guard then assumes BYTES_PER_DOF_OUT_OF_CORE instead of BYTES_PER_DOF.
    min_gap: the least gap [mm] the exact method keeps between yarns in contact, and between a yarn
    and a mould's platens (default 0: the yarns touch): added to every contact node's margin, so the
    yarns' sections, and so their volumes, are unchanged (a conforming tet mesh needs a gap of
    matrix between the yarns: volume/tet/). settle_tol: where the yarns flatten, their
    forces give the platens' pressure: a solve whose yarns settled to displacement_tol with its
    forces out of balance (above solver.newton.DUAL_RTOL) goes on until a full step moves less than
    this [mm] (None: it stops, and its forces are refitted; a compaction's steps set it, see
    compaction.STEP_TOL).
    """

    method: str = "exact"
    max_iterations: int = 100
    penetration_tol: float = 1e-6
    displacement_tol: float = 1e-6
    petsc: dict = field(default_factory=lambda: dict(DIRECT_LDLT))
    out_of_core: bool = False
    min_gap: float = 0.0
    settle_tol: float | None = None

    def __post_init__(self):
        if self.method not in METHODS:
            raise TextileError(f"solver method must be one of {', '.join(map(repr, METHODS))}, got {self.method!r}")
        check_count("max_iterations", self.max_iterations, 1, MAX_ITERATIONS)
        check_positive("penetration_tol", self.penetration_tol)
        check_positive("displacement_tol", self.displacement_tol)
        if self.settle_tol is not None:
            check_positive("settle_tol", self.settle_tol)
        object.__setattr__(self, "min_gap", check_positive("min_gap", self.min_gap, allow_zero=True))
        if self.min_gap > 0 and self.method != "exact":
            raise TextileError("min_gap needs the exact contact method (the penalty method cannot hold a gap)")

    @property
    def linear_options(self) -> dict:
        """The PETSc options of the linear solves (petsc, with OUT_OF_CORE when asked)."""
        return {**self.petsc, **OUT_OF_CORE} if self.out_of_core else dict(self.petsc)

    @property
    def bytes_per_dof(self) -> float:
        """The memory a run needs per unknown [bytes] (measured by `make bench`), for the guard."""
        return BYTES_PER_DOF_OUT_OF_CORE if self.out_of_core else BYTES_PER_DOF


@dataclass
class Solution:
    """Displacements per yarn and how they were found.

    w: per yarn, its displacement [mm] (a Function on its mid-surface's P2 space); dt: per yarn,
    its change of thickness [mm] where the yarns flatten (Compaction), else None. gap, contact:
    per yarn, its gap to the yarn below [mm] (0 where nothing is below) and the contact state
    (1 where a constraint or the penalty is active), for output. history: one dict per Newton step.
    max_penetration: largest -g at the overlap nodes [mm]; penetration_volume: the integral of
    max(0, -g) over the overlaps [mm^3]. reason: why the iteration stopped.
    """

    w: list[dolfinx.fem.Function]
    gap: list[dolfinx.fem.Function]
    contact: list[dolfinx.fem.Function]
    iterations: int
    updates: int
    history: list[dict]
    max_penetration: float
    penetration_volume: float
    converged: bool
    reason: str
    times: dict = field(default_factory=dict)
    unknowns: object = None  # this rank's part of the unknowns vector (to start a related solve from)
    dt: list | None = None
    pressure: float | None = None  # a closed mould's platen pressure [N/mm^2 = MPa]: its bottom force over the cell

    def __repr__(self) -> str:
        state = "converged" if self.converged else "not converged"
        return (f"<Solution: {state} in {self.iterations} Newton steps, {len(self.w)} yarns, "
                f"max penetration {self.max_penetration:.3g} mm>")
