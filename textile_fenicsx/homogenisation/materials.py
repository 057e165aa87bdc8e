"""Constituent materials, their presets and files, and the yarn's properties by Chamis' micromechanics.

Units: moduli in MPa, thermal conductivities in W/(m K); axis 1 of an anisotropic material is the
fibre direction (a yarn's material axes: constants.frames).

Presets (`PRESETS`, looked up by `material(name)`):
- "e-glass": E-glass fibre (Gevetex 21xK43), isotropic, E = 80 GPa, nu = 0.2 (G = 33.3 GPa):
  P.D. Soden, M.J. Hinton, A.S. Kaddour, "Lamina properties, lay-up configurations and loading
  conditions for a range of fibre-reinforced composite laminates", Compos. Sci. Technol. 58 (1998)
  1011-1022, Table 1. k = 1.3 W/(m K): typical handbook value for E-glass (not in Soden et al.).
- "t300": carbon fibre T300, transversely isotropic, E1 = 230 GPa, E2 = 15 GPa, G12 = 15 GPa,
  G23 = 7 GPa, nu12 = 0.2 (nu23 = 0.07): Soden et al. (1998), Table 1. k1 = 10.5 W/(m K): Toray's
  T300 data sheet (CFA-001: 0.025 cal/(cm s C)); k2 = 1.0 W/(m K): an assumed value (no source
  found for the transverse conductivity; give a file if it matters).
- "epoxy": epoxy matrix (MY750/HY917/DY063), isotropic, E = 3.35 GPa, nu = 0.35 (G = 1.24 GPa):
  Soden et al. (1998), Table 1. k = 0.2 W/(m K): typical value for cured epoxy (not in Soden et al.).

Files (TOML, `read_material`): `symmetry` = "isotropic" (E, nu; k), "transversely_isotropic" (E1, E2,
G12, nu12 and one of G23 or nu23; k1, k2) or "orthotropic" (E1, E2, E3, G12, G13, G23, nu12, nu13,
nu23; k1, k2, k3); optional `name` and `source`; conductivities are optional (no conductivity: no
thermal homogenisation). Every other key is an error.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from textile_fenicsx.common.errors import FormatError, TextileError, check_positive
from textile_fenicsx.homogenisation.constants import orthotropic_stiffness

__all__ = ["PRESETS", "Isotropic", "Material", "Orthotropic", "TransverselyIsotropic", "chamis", "material",
           "read_material", "yarn_material"]


@dataclass(frozen=True)
class Isotropic:
    """E [MPa], nu [-]; k [W/(m K)] or None."""
    name: str
    E: float
    nu: float
    k: float | None = None
    source: str = ""

    def constants(self) -> tuple:
        G = self.E / (2 * (1 + self.nu))
        return (self.E, self.E, self.E, G, G, G, self.nu, self.nu, self.nu)

    def conductivities(self) -> tuple | None:
        return None if self.k is None else (self.k,) * 3


@dataclass(frozen=True)
class TransverselyIsotropic:
    """Isotropic across axis 1 (the fibre): E1, E2 = E3, G12 = G13, G23 [MPa], nu12 = nu13 [-]
    (nu23 = E2 / (2 G23) - 1); k1 along and k2 across the fibre [W/(m K)] or None."""
    name: str
    E1: float
    E2: float
    G12: float
    nu12: float
    G23: float
    k1: float | None = None
    k2: float | None = None
    source: str = ""

    @property
    def nu23(self) -> float:
        return self.E2 / (2 * self.G23) - 1

    def constants(self) -> tuple:
        return (self.E1, self.E2, self.E2, self.G12, self.G12, self.G23, self.nu12, self.nu12, self.nu23)

    def conductivities(self) -> tuple | None:
        return None if self.k1 is None or self.k2 is None else (self.k1, self.k2, self.k2)


@dataclass(frozen=True)
class Orthotropic:
    """Nine constants in the material axes: E1, E2, E3, G12, G13, G23 [MPa], nu12, nu13, nu23 [-]
    (nu_ij: contraction along j under stress along i); k1, k2, k3 [W/(m K)] or None."""
    name: str
    E1: float
    E2: float
    E3: float
    G12: float
    G13: float
    G23: float
    nu12: float
    nu13: float
    nu23: float
    k1: float | None = None
    k2: float | None = None
    k3: float | None = None
    source: str = ""

    def constants(self) -> tuple:
        return (self.E1, self.E2, self.E3, self.G12, self.G13, self.G23, self.nu12, self.nu13, self.nu23)

    def conductivities(self) -> tuple | None:
        ks = (self.k1, self.k2, self.k3)
        return None if any(k is None for k in ks) else ks


Material = Isotropic | TransverselyIsotropic | Orthotropic

_SOURCE = "Soden, Hinton & Kaddour, Compos. Sci. Technol. 58 (1998) 1011-1022, Table 1"
PRESETS: dict[str, Material] = {
    "e-glass": Isotropic("e-glass", E=80e3, nu=0.2, k=1.3, source=f"{_SOURCE}; k: typical handbook value"),
    "t300": TransverselyIsotropic("t300", E1=230e3, E2=15e3, G12=15e3, nu12=0.2, G23=7e3, k1=10.5, k2=1.0,
                                  source=f"{_SOURCE}; k1: Toray T300 data sheet; k2: assumed"),
    "epoxy": Isotropic("epoxy", E=3.35e3, nu=0.35, k=0.2, source=f"{_SOURCE}; k: typical value"),
}


def stiffness(m: Material) -> np.ndarray:
    """The 6 x 6 stiffness [MPa] in the material's axes (Voigt 11, 22, 33, 23, 13, 12)."""
    return orthotropic_stiffness(*m.constants())


def conductivity(m: Material) -> np.ndarray | None:
    """The 3 x 3 conductivity [W/(m K)] in the material's axes, or None."""
    k = m.conductivities()
    return None if k is None else np.diag(k)


def check_material(m: Material) -> Material:
    """Return m if its constants are positive (moduli, conductivities) and give a positive-definite
    stiffness; else raise TextileError naming the material and the constant."""
    for f in fields(m):
        value = getattr(m, f.name)
        if f.name[0] in "EGk" and value is not None:
            check_positive(f"material {m.name!r}: {f.name}", value)
    E1, E2, E3, G12, G13, G23, nu12, nu13, nu23 = m.constants()
    S3 = np.array([[1 / E1, -nu12 / E1, -nu13 / E1], [-nu12 / E1, 1 / E2, -nu23 / E2],
                   [-nu13 / E1, -nu23 / E2, 1 / E3]])
    if not np.all(np.isfinite(S3)) or np.linalg.eigvalsh(S3).min() <= 0:
        raise TextileError(f"material {m.name!r}: the Poisson's ratios (nu12 {nu12:g}, nu13 {nu13:g}, "
                           f"nu23 {nu23:g}) give no positive-definite stiffness with these moduli")
    return m


def material(spec) -> Material:
    """A material: a Material as it is (checked), a preset's name, or the path of a TOML file."""
    if isinstance(spec, (Isotropic, TransverselyIsotropic, Orthotropic)):
        return check_material(spec)
    text = str(spec)
    if text.lower() in PRESETS:
        return PRESETS[text.lower()]
    path = Path(text)
    if path.suffix.lower() == ".toml" or path.is_file():
        return read_material(path)
    raise TextileError(f"unknown material {text!r}: use a preset ({', '.join(PRESETS)}) or a .toml file")


_KEYS = {
    "isotropic": (Isotropic, ("E", "nu"), ("k",)),
    "transversely_isotropic": (TransverselyIsotropic, ("E1", "E2", "G12", "nu12"), ("k1", "k2")),
    "orthotropic": (Orthotropic, ("E1", "E2", "E3", "G12", "G13", "G23", "nu12", "nu13", "nu23"),
                    ("k1", "k2", "k3")),
}


def read_material(path) -> Material:
    """The material of a TOML file (module docstring); FormatError naming the file and key if it is
    malformed, TextileError if its constants are not admissible."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except OSError as e:
        raise FormatError(f"material file {path}: cannot be read ({e.strerror or e})") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise FormatError(f"material file {path}: not valid TOML ({e})") from None
    symmetry = data.pop("symmetry", None)
    if symmetry not in _KEYS:
        raise FormatError(f"material file {path}: 'symmetry' must be one of {', '.join(_KEYS)}, got {symmetry!r}")
    cls, required, optional = _KEYS[symmetry]
    name, source = data.pop("name", path.stem), data.pop("source", str(path))
    if not isinstance(name, str) or not isinstance(source, str):
        raise FormatError(f"material file {path}: 'name' and 'source' must be strings")
    values = {}
    if symmetry == "transversely_isotropic":
        if ("G23" in data) == ("nu23" in data):
            raise FormatError(f"material file {path}: give exactly one of 'G23' and 'nu23'")
        if "nu23" in data:
            nu23 = _number(path, "nu23", data.pop("nu23"))
            values["G23"] = _number(path, "E2", data.get("E2", 0.0)) / (2 * (1 + nu23))
        else:
            values["G23"] = _number(path, "G23", data.pop("G23"))
    missing = [key for key in required if key not in data]
    if missing:
        raise FormatError(f"material file {path}: {symmetry} needs {', '.join(missing)}")
    unknown = sorted(set(data) - set(required) - set(optional))
    if unknown:
        raise FormatError(f"material file {path}: unknown key(s) {', '.join(unknown)} for a {symmetry} material")
    values.update({key: _number(path, key, value) for key, value in data.items()})
    return check_material(cls(name=name, source=source, **values))


def _number(path: Path, key: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise FormatError(f"material file {path}: {key} must be a number, got {value!r}")
    return float(value)


def chamis(fibre: Material, matrix: Material, vf) -> dict[str, np.ndarray]:
    """The yarn's transversely isotropic constants at fibre volume fractions vf (scalar or array).

    C.C. Chamis, "Simplified composite micromechanics equations for hygral, thermal and mechanical
    properties", SAMPE Quarterly 15(3) (1984) 14-23 (also NASA TM-83320, 1983), with s = sqrt(vf):
        E1 = vf Ef1 + (1 - vf) Em                 nu12 = vf nuf12 + (1 - vf) num
        E2 = Em / (1 - s (1 - Em/Ef2))            G12 = Gm / (1 - s (1 - Gm/Gf12))
        G23 = Gm / (1 - s (1 - Gm/Gf23))          nu23 = E2 / (2 G23) - 1
        k1 = vf kf1 + (1 - vf) km                 k2 = (1 - s) km + s km / (1 - s (1 - km/kf2))
    The matrix must be isotropic, the fibre isotropic or transversely isotropic. Returns arrays E1,
    E2, G12, nu12, G23 [MPa] and k1, k2 [W/(m K)] (None without both conductivities).
    """
    if not isinstance(matrix, Isotropic):
        raise TextileError(f"matrix {matrix.name!r}: Chamis' micromechanics needs an isotropic matrix")
    if isinstance(fibre, Orthotropic):
        raise TextileError(f"fibre {fibre.name!r}: Chamis' micromechanics needs an isotropic or transversely "
                           "isotropic fibre, not an orthotropic one")
    vf = np.asarray(vf, dtype=float)
    if not np.all(np.isfinite(vf)) or np.any((vf < 0) | (vf > 1)):
        bad = vf[~((vf >= 0) & (vf <= 1))]
        raise TextileError(f"yarn fibre volume fraction must be in [0, 1], got {bad.ravel()[0]!r}"
                           f"{f' (and {bad.size - 1} more)' if bad.size > 1 else ''}")
    Ef1, Ef2, _, Gf12, _, Gf23, nuf12, _, _ = fibre.constants()
    Em, _, _, Gm, _, _, num, _, _ = matrix.constants()
    s = np.sqrt(vf)
    out = {"E1": vf * Ef1 + (1 - vf) * Em, "E2": Em / (1 - s * (1 - Em / Ef2)),
           "G12": Gm / (1 - s * (1 - Gm / Gf12)), "nu12": vf * nuf12 + (1 - vf) * num,
           "G23": Gm / (1 - s * (1 - Gm / Gf23)), "k1": None, "k2": None}
    kf, km = fibre.conductivities(), matrix.conductivities()
    if kf is not None and km is not None:
        out["k1"] = vf * kf[0] + (1 - vf) * km[0]
        out["k2"] = (1 - s) * km[0] + s * km[0] / (1 - s * (1 - km[0] / kf[1]))
    return out


def yarn_material(fibre: Material, matrix: Material, vf: float) -> TransverselyIsotropic:
    """The yarn's material at fibre volume fraction vf by Chamis' equations (`chamis`)."""
    p = chamis(fibre, matrix, float(vf))
    k1, k2 = (None, None) if p["k1"] is None else (float(p["k1"]), float(p["k2"]))
    return TransverselyIsotropic(f"{fibre.name}/{matrix.name} at Vf {float(vf):g}", float(p["E1"]), float(p["E2"]),
                                 float(p["G12"]), float(p["nu12"]), float(p["G23"]), k1, k2,
                                 "Chamis, SAMPE Quarterly 15(3) 1984")
