"""Voigt notation: stiffness from engineering constants and back, rotations, Voigt and Reuss bounds.

Voigt order (everywhere in this package and in stiffness.json): 11, 22, 33, 23, 13, 12 (xx, yy, zz,
yz, xz, xy), with ENGINEERING shear strains g_ij = 2 e_ij, so that sig = C eps and S = C^-1 is the
compliance whose entries are the usual 1/E, -nu/E and 1/G. Moduli in MPa.

Engineering constants from S: E1 = 1/S11, E2 = 1/S22, E3 = 1/S33, G23 = 1/S44, G13 = 1/S55,
G12 = 1/S66, nu_ij = -S_ij / S_ii (the contraction along j under a stress along i). Every function
takes stacks of matrices (..., 6, 6) so that a whole mesh's cells go through at once.
"""

from __future__ import annotations

import numpy as np

__all__ = ["ENGINEERING_NAMES", "VOIGT_ORDER", "bond_matrix", "bounds", "engineering_constants",
           "frames", "orthotropic_stiffness", "rotate_conductivity", "rotate_stiffness"]

VOIGT_ORDER = ("11", "22", "33", "23", "13", "12")
_PAIRS = ((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))
ENGINEERING_NAMES = ("Ex", "Ey", "Ez", "Gxy", "Gxz", "Gyz", "nuxy", "nuxz", "nuyz")


def orthotropic_stiffness(E1, E2, E3, G12, G13, G23, nu12, nu13, nu23) -> np.ndarray:
    """C = S^-1 [MPa] in the material axes from the nine constants (scalars or equal-shape arrays).

    S = [[1/E1, -nu12/E1, -nu13/E1], [., 1/E2, -nu23/E2], [., ., 1/E3]] (symmetric) and
    diag(1/G23, 1/G13, 1/G12) in Voigt order 11, 22, 33, 23, 13, 12.
    """
    E1, E2, E3, G12, G13, G23, nu12, nu13, nu23 = np.broadcast_arrays(
        *(np.asarray(v, dtype=float) for v in (E1, E2, E3, G12, G13, G23, nu12, nu13, nu23)))
    S = np.zeros(E1.shape + (6, 6))
    S[..., 0, 0], S[..., 1, 1], S[..., 2, 2] = 1 / E1, 1 / E2, 1 / E3
    S[..., 0, 1] = S[..., 1, 0] = -nu12 / E1
    S[..., 0, 2] = S[..., 2, 0] = -nu13 / E1
    S[..., 1, 2] = S[..., 2, 1] = -nu23 / E2
    S[..., 3, 3], S[..., 4, 4], S[..., 5, 5] = 1 / G23, 1 / G13, 1 / G12
    return np.linalg.inv(S)


def engineering_constants(C: np.ndarray) -> dict[str, float]:
    """Ex Ey Ez Gxy Gxz Gyz [MPa] and nuxy nuxz nuyz of a 6 x 6 stiffness, from S = C^-1."""
    S = np.linalg.inv(np.asarray(C, dtype=float))
    values = (1 / S[0, 0], 1 / S[1, 1], 1 / S[2, 2], 1 / S[5, 5], 1 / S[4, 4], 1 / S[3, 3],
              -S[0, 1] / S[0, 0], -S[0, 2] / S[0, 0], -S[1, 2] / S[1, 1])
    return {name: float(v) for name, v in zip(ENGINEERING_NAMES, values)}


def frames(a: np.ndarray) -> np.ndarray:
    """Material frames Q (..., 3, 3), columns (e1, e2, e3), from fibre directions a (..., 3).

    e1 = a / |a|; e2 = z x e1 normalised (in the xy-plane, across the fibre; y x e1 if the fibre is
    along z); e3 = e1 x e2. a = x gives the identity. A transversely isotropic material does not
    depend on the choice of e2; an orthotropic one has its axis 2 there.
    """
    a = np.asarray(a, dtype=float)
    e1 = a / np.linalg.norm(a, axis=-1, keepdims=True)
    e2 = np.cross(np.array([0.0, 0.0, 1.0]), e1)
    along_z = np.linalg.norm(e2, axis=-1) < 1e-8
    e2[along_z] = np.cross(np.array([0.0, 1.0, 0.0]), e1[along_z])
    e2 /= np.linalg.norm(e2, axis=-1, keepdims=True)
    return np.stack([e1, e2, np.cross(e1, e2)], axis=-1)


def bond_matrix(Q: np.ndarray) -> np.ndarray:
    """Bond's 6 x 6 matrix M (...) with sig_v(global) = M sig_v(material) for sig = Q sig' Q^T.

    With engineering shear strains eps_v(material) = M^T eps_v(global), hence C = M C' M^T.
    """
    Q = np.asarray(Q, dtype=float)
    M = np.empty(Q.shape[:-2] + (6, 6))
    for p, (i, j) in enumerate(_PAIRS):
        for q, (k, l) in enumerate(_PAIRS):
            M[..., p, q] = Q[..., i, k] * Q[..., j, l] + (Q[..., i, l] * Q[..., j, k] if k != l else 0.0)
    return M


def rotate_stiffness(C: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """C (global) = M C' M^T for material stiffnesses C' and frames Q (stacks broadcast)."""
    M = bond_matrix(Q)
    return M @ C @ np.swapaxes(M, -1, -2)


def rotate_conductivity(K: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """K (global) = Q K' Q^T."""
    return Q @ K @ np.swapaxes(Q, -1, -2)


def bounds(tensors: np.ndarray, volumes: np.ndarray, comm=None) -> tuple[np.ndarray, np.ndarray]:
    """Voigt and Reuss bounds (the volume averages of the tensors and of their inverses, inverted).

    tensors (n, m, m) per cell, volumes (n,) [mm^3]; comm: sum over ranks (each rank passes the
    cells it owns). Any effective tensor A satisfies Reuss <= A <= Voigt (differences positive
    semi-definite; Hill 1952).
    """
    w = np.asarray(volumes, dtype=float)
    local = np.concatenate([np.einsum("c,cij->ij", w, tensors).ravel(),
                            np.einsum("c,cij->ij", w, np.linalg.inv(tensors)).ravel(), [w.sum()]])
    total = local.copy()
    if comm is not None:
        comm.Allreduce(local, total)
    m = tensors.shape[-1]
    voigt = total[: m * m].reshape(m, m) / total[-1]
    reuss = np.linalg.inv(total[m * m: 2 * m * m].reshape(m, m) / total[-1])
    return voigt, reuss
