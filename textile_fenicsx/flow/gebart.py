"""The permeability inside a yarn: Gebart's laws for fibres in hexagonal packing (Gebart 1992,
J. Compos. Mater. 26(8)), and the tensor of a yarn element from its fibre direction.

Along the fibres, K_axial = 8 r^2 / c (1 - Vf)^3 / Vf^2 with c = 53 for hexagonal packing; across
them, K_transverse = C1 (sqrt(Vmax / Vf) - 1)^(5/2) r^2 with C1 = 16 / (9 pi sqrt 6) and
Vmax = pi / (2 sqrt 3), the densest packing, at which the transverse flow stops. r is the fibre
radius and Vf the yarn's own fibre fraction. A yarn element's tensor is
K = K_axial a (x) a + K_transverse (I - a (x) a), a its fibre direction. Gebart's laws are an upper
bound for real, random packings: across the fibres, 6-10 x lower values are measured at Vf > 0.6.
"""

from __future__ import annotations

import numpy as np

__all__ = ["C1", "C_AXIAL", "VMAX", "axial", "tensors", "transverse"]

C_AXIAL = 53.0
C1 = 16.0 / (9.0 * np.pi * np.sqrt(6.0))
VMAX = np.pi / (2.0 * np.sqrt(3.0))


def axial(vf: np.ndarray, radius: float) -> np.ndarray:
    """Gebart's permeability along the fibres [radius's unit squared]."""
    vf = np.asarray(vf, float)
    return 8.0 * radius**2 / C_AXIAL * (1.0 - vf) ** 3 / vf**2


def transverse(vf: np.ndarray, radius: float) -> np.ndarray:
    """Gebart's permeability across the fibres [radius's unit squared]; 0 at and beyond VMAX."""
    vf = np.asarray(vf, float)
    return C1 * np.clip(np.sqrt(VMAX / vf) - 1.0, 0.0, None) ** 2.5 * radius**2


def tensors(direction: np.ndarray, k_axial: np.ndarray, k_transverse: np.ndarray) -> np.ndarray:
    """(n, 3, 3) tensors K = k_axial a (x) a + k_transverse (I - a (x) a) of unit directions a (n, 3)."""
    a = np.asarray(direction, float).reshape(-1, 3)
    aa = np.einsum("ni,nj->nij", a, a)
    kt = np.broadcast_to(np.asarray(k_transverse, float), len(a))[:, None, None]
    ka = np.broadcast_to(np.asarray(k_axial, float), len(a))[:, None, None]
    return kt * np.eye(3) + (ka - kt) * aa
