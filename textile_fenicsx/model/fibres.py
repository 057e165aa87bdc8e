"""Fibre data of a yarn, and the units TexGen stores beside each value.

TexGen keeps a yarn's fibre data (and the textile's default for its yarns) as attributes with a
unit beside each value, e.g. ``FibreDiameterValue="7e-06" FibreDiameterUnits="m"``. The model holds
them in fixed units (mm, mm^2, g/cm^3, tex); `from_tg3` converts, `tg3_attributes` writes them back.

The fibre cross-section of a yarn, A_f [mm^2], is the first of these that its data allows (TexGen's
own order, CYarn::GetFibreArea, checked with pytexgen 1.2.1): the fibre area given; linear density
over fibre density (tex / (1000 rho), rho in g/cm^3); fibres per yarn x pi d^2 / 4. A yarn's
intra-yarn fibre volume fraction is A_f over its section area.
"""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass, fields
from typing import Any

from textile_fenicsx.common import limits
from textile_fenicsx.common.errors import FormatError, TextileError

log = logging.getLogger(__name__)

# Factors to the model's units, by TexGen's unit strings (and their common spellings).
_LENGTH_MM = {"m": 1e3, "cm": 10.0, "mm": 1.0, "um": 1e-3, "µm": 1e-3, "micron": 1e-3, "nm": 1e-6,
              "in": 25.4, "ft": 304.8}
_DENSITY_G_CM3 = {"g/cm^3": 1.0, "g/cc": 1.0, "kg/m^3": 1e-3, "g/m^3": 1e-6, "kg/dm^3": 1.0, "g/mm^3": 1e3,
                  "kg/l": 1.0, "g/ml": 1.0, "lb/in^3": 27.679904710203}
_LINEAR_TEX = {"tex": 1.0, "g/km": 1.0, "ktex": 1e3, "dtex": 0.1, "den": 1 / 9, "denier": 1 / 9, "g/m": 1e3,
               "kg/m": 1e6, "kg/km": 1e3}

# The bounds of each quantity, wide for technical fibres (carbon 5-7 um, glass 9-24 um, aramid 12 um;
# 1k-320k fibres per tow; 1.4-2.6 g/cm^3; 10-30 000 tex).
_BOUNDS = {"count": (1.0, 1e7, ""), "diameter": (1e-4, 1.0, " mm"), "area": (1e-8, 1e4, " mm^2"),
           "density": (0.1, 25.0, " g/cm^3"), "linear_density": (1e-3, 1e7, " tex")}


@dataclass(frozen=True)
class Fibres:
    """A yarn's fibre data; every field optional, as in TexGen.

    count: fibres per yarn. diameter: one fibre's diameter [mm]. area: the fibres' total cross-
    section in the yarn [mm^2]. density: the fibre material's density [g/cm^3]. linear_density:
    the yarn's mass per length [tex = g/km].
    """

    count: float | None = None
    diameter: float | None = None
    area: float | None = None
    density: float | None = None
    linear_density: float | None = None

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if value is not None:
                lo, hi, unit = _BOUNDS[f.name]
                object.__setattr__(self, f.name, limits.check_range(f"fibre {f.name.replace('_', ' ')}", value,
                                                                    lo, hi, unit))

    def __repr__(self) -> str:
        given = ", ".join(f"{name}={value:g}" for name, value in self.as_dict().items())
        return f"Fibres({given})"

    def fibre_area(self) -> float | None:
        """The fibres' cross-section in the yarn [mm^2] (TexGen's order, module docstring), or None."""
        if self.area is not None:
            return self.area
        if self.linear_density is not None and self.density is not None:
            return self.linear_density / (1000.0 * self.density)
        if self.count is not None and self.diameter is not None:
            return self.count * math.pi * self.diameter**2 / 4
        return None

    def as_dict(self) -> dict[str, float]:
        """The given fields by name (the model's units)."""
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None}


# TexGen's attribute names: (value attribute, units attribute, (the model's unit, the table of units,
# the power of length) or None for a count)
TG3_ATTRIBUTES: dict[str, tuple[str, str, tuple[str, dict[str, float], int]] | tuple[str, None, None]] = {
    "count": ("FibresPerYarn", None, None),
    "diameter": ("FibreDiameterValue", "FibreDiameterUnits", ("mm", _LENGTH_MM, 1)),
    "area": ("FibreAreaValue", "FibreAreaUnits", ("mm^2", _LENGTH_MM, 2)),
    "density": ("FibreDensityValue", "FibreDensityUnits", ("g/cm^3", _DENSITY_G_CM3, 1)),
    "linear_density": ("YarnLinearDensityValue", "YarnLinearDensityUnits", ("tex", _LINEAR_TEX, 1)),
}


def _factor(unit: str, table: dict[str, float], power: int, where: str) -> float:
    """The factor that takes a value in `unit` to the model's unit; a FormatError naming an unknown one."""
    text = unit.strip().replace(" ", "")
    if power == 2:
        match = re.fullmatch(r"(.+?)(\^2|2|²)", text)
        if match and match.group(1) in table:
            return table[match.group(1)] ** 2
    else:
        for key in (text, text.lower()):
            if key in table:
                return table[key]
    known = ", ".join(f"{u}^2" if power == 2 else u for u in table)
    raise FormatError(f"{where}: unknown unit {unit!r} (known: {known})")


def from_tg3(el: Any, where: str) -> Fibres | None:
    """The fibre data of a TexGen <Yarn> or <Textile> element, converted to the model's units; None
    when it has none. A value TexGen marks as unset (0, or a unit-less value of a dimensioned
    quantity) is left out."""
    values: dict[str, float] = {}
    for name, (value_attr, units_attr, unit) in TG3_ATTRIBUTES.items():
        text = el.get(value_attr)
        if text is None:
            continue
        try:
            value = float(text)
        except ValueError:
            raise FormatError(f"{where}: attribute {value_attr}={text!r} is not a number") from None
        if not math.isfinite(value):
            raise FormatError(f"{where}: attribute {value_attr}={text!r} is not finite")
        if value <= 0:  # TexGen writes 0 for "not given"
            continue
        if unit is not None and units_attr is not None:
            _, table, power = unit
            given = el.get(units_attr)
            if given is None:
                raise FormatError(f"{where}: {value_attr}={text} has no {units_attr}")
            value *= _factor(given, table, power, f"{where} {units_attr}")
        values[name] = value
    if not values:
        return None
    try:
        return Fibres(**values)
    except TextileError as e:
        raise FormatError(f"{where}: {e} (after conversion to the model's units)") from None


def tg3_attributes(fibres: Fibres) -> dict[str, str]:
    """TexGen's attributes for the fibre data, in the model's units written beside each value."""
    out = {}
    for name, value in fibres.as_dict().items():
        value_attr, units_attr, unit = TG3_ATTRIBUTES[name]
        whole = unit is None and float(value).is_integer()
        out[value_attr] = repr(int(value)) if whole else repr(float(value))
        if unit is not None and units_attr is not None:
            out[units_attr] = unit[0]
    return out


def from_dict(d: Any, where: str) -> Fibres:
    """Fibre data from a TOML/JSON table: count, diameter [mm], area [mm^2], density [g/cm^3],
    linear_density [tex]."""
    if not isinstance(d, dict):
        raise FormatError(f"{where}: expected a table")
    unknown = set(d) - {f.name for f in fields(Fibres)}
    if unknown:
        raise FormatError(f"{where}: unknown key(s) {sorted(unknown)} (known: count, diameter, area, density, "
                          "linear_density)")
    try:
        return Fibres(**d)
    except TextileError as e:
        raise FormatError(f"{where}: {e}") from None


# The intra-yarn fibre volume fraction assumed for a yarn without fibre data (with a warning): a
# typical packing of a tow in a woven fabric, whose measured values lie around 0.6-0.7.
DEFAULT_YARN_VF = 0.65
# The densest packing of equal round fibres, hexagonal [-]: the bound of any intra-yarn fraction
# (the volume mesh's, --yarn-vf's) and the compaction law's default maximum
HEXAGONAL = math.pi / (2 * math.sqrt(3))


def check_yarn_vf(vf: float) -> float:
    """A yarn fibre volume fraction given for every yarn (--yarn-vf), checked against HEXAGONAL."""
    return limits.check_range("yarn fibre volume fraction (--yarn-vf)", vf, 1e-6, HEXAGONAL)
