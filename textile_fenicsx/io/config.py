"""The project's own model format: a human-editable TOML or JSON description of a textile.

Either a named weave with its options (see `weaves.build`):

    [weave]
    type = "crowfoot_satin"
    spacing = 2.8
    width = 2.5
    height = 0.35
    thickness = 0.7

or a generic yarn list (what `save_model` writes, JSON):

    [cell]
    lx = 11.2
    ly = 11.2                      # optional: x0, y0, z_range = [zmin, zmax]
    [[yarns]]
    nodes = [[0, 0, 0.175], [2.8, 0, 0.525], [5.6, 0, 0.175]]
    interpolation = "bezier"       # or "cubic", "linear"
    repeats = [[5.6, 0, 0], [0, 5.6, 0]]
    section = {type = "ellipse", width = 2.5, height = 0.35}
    # instead of section: node_sections = [{...}, ...] (one per node) or
    # position_sections = {positions = [...], sections = [{...}, ...]}

Section tables: type = ellipse | lenticular | power_ellipse | polygon | hybrid, with width, height
and (lenticular) distortion, (power_ellipse) power and x_offset, (polygon) points = [[s, u], ...],
(hybrid: TexGen's CSectionHybrid, sections.Hybrid) divisions = [t, ...] and pieces = [{...}, ...],
one per division, where a piece may also be {type = "flat", width = w} (no height).
A top-level `name` and `[resolution]` (spacing, section_points, per_segment) are optional. Fibre data,
`fibres = {count = 12000, diameter = 0.007}` (also area [mm^2], density [g/cm^3], linear_density
[tex]: fibres.Fibres), may be given per yarn, or once at the top level for every yarn without its own.
A stack of plies (plies.stack) has `plies = [n1, n2, ...]` at the top level: the yarns of each ply,
which come ply by ply. Unknown keys are errors naming the key, so a typo never passes silently.
"""

import json
import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from textile_fenicsx.common.errors import FormatError, TextileError
from textile_fenicsx.common.files import atomic_path
from textile_fenicsx.common.limits import (
    MAX_NODES_PER_YARN,
    MAX_POLYGON_POINTS,
    MAX_YARNS,
    check_file_size,
    check_many,
)
from textile_fenicsx.model import fibres as fibre_data
from textile_fenicsx.model.sections import (
    MAX_HYBRID_DEPTH,
    Ellipse,
    Flat,
    Hybrid,
    Lenticular,
    Polygon,
    PowerEllipse,
    Section,
)
from textile_fenicsx.model.textile import Cell, Resolution, Textile
from textile_fenicsx.model.yarn import ConstantSection, NodeSections, PositionSections, Yarn

SECTION_TYPES: dict[str, type] = {"ellipse": Ellipse, "lenticular": Lenticular, "power_ellipse": PowerEllipse,
                                  "polygon": Polygon, "hybrid": Hybrid}


def _keys(table, where: str, allowed: set, required: set | frozenset = frozenset()):
    if not isinstance(table, dict):
        raise FormatError(f"{where}: expected a table, got {type(table).__name__}")
    unknown = set(table) - allowed
    if unknown:
        raise FormatError(f"{where}: unknown key(s) {sorted(unknown)}; allowed: {sorted(allowed)}")
    missing = set(required) - set(table)
    if missing:
        raise FormatError(f"{where}: missing key(s) {sorted(missing)}")


def _array(value, where: str, shape_tail: tuple) -> np.ndarray:
    try:
        a = np.array(value, dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise FormatError(f"{where}: expected numbers, got {value!r:.80}") from None
    if a.ndim != 1 + len(shape_tail) or a.shape[1:] != shape_tail:
        raise FormatError(f"{where}: expected a list of {shape_tail or 'numbers'}, got shape {a.shape}")
    return a


def section_from_dict(d, where: str, depth: int = 0) -> Section:
    """A section table as a Section; depth > 0: a piece of a hybrid section (that deep), which may
    be flat."""
    _keys(d, where, {"type", "width", "height", "power", "x_offset", "distortion", "points", "divisions", "pieces"},
          {"type"})
    kind = d["type"]
    known = SECTION_TYPES | ({"flat": Flat} if depth else {})
    if not isinstance(kind, str) or kind not in known:
        hint = " (flat: only as a piece of a hybrid section)" if kind == "flat" else ""
        raise FormatError(f"{where}: section type {kind!r} unknown; choose from {sorted(known)}{hint}")
    fields = {"ellipse": ("width", "height"), "lenticular": ("width", "height", "distortion"),
              "power_ellipse": ("width", "height", "power", "x_offset"), "polygon": ("points",),
              "hybrid": ("divisions", "pieces"), "flat": ("width",)}[kind]
    extra = set(d) - {"type"} - set(fields)
    if extra:
        raise FormatError(f"{where}: key(s) {sorted(extra)} do not apply to a {kind} section")
    try:
        if kind == "polygon":
            if "points" not in d:
                raise FormatError(f"{where}: polygon section needs points")
            return Polygon(tuple(map(tuple, _array(d["points"], f"{where}.points", (2,)))))
        if kind == "hybrid":
            return _hybrid_from_dict(d, where, depth)
        return known[kind](**{k: d[k] for k in fields if k in d})
    except TypeError as e:
        raise FormatError(f"{where}: {e}") from None
    except FormatError:
        raise
    except TextileError as e:
        raise FormatError(f"{where}: {e}") from None


def _hybrid_from_dict(d: dict, where: str, depth: int) -> Hybrid:
    """A hybrid section: divisions [t, ...] and pieces [section table, ...], one per division."""
    if depth >= MAX_HYBRID_DEPTH:
        raise FormatError(f"{where}: hybrid sections nested more than {MAX_HYBRID_DEPTH} deep")
    if "divisions" not in d or "pieces" not in d or not isinstance(d["pieces"], list):
        raise FormatError(f"{where}: a hybrid section needs divisions and a list of pieces")
    check_many(f"{where}.pieces", len(d["pieces"]), MAX_POLYGON_POINTS, FormatError)
    divisions = tuple(_array(d["divisions"], f"{where}.divisions", ()))
    pieces = tuple(section_from_dict(x, f"{where}.pieces[{k}]", depth + 1) for k, x in enumerate(d["pieces"]))
    return Hybrid(divisions, pieces)


def section_to_dict(s: Section) -> dict:
    if isinstance(s, Polygon):
        return {"type": "polygon", "points": [list(p) for p in s.vertices]}
    if isinstance(s, Hybrid):
        return {"type": "hybrid", "divisions": list(s.divisions), "pieces": [section_to_dict(x) for x in s.pieces]}
    if isinstance(s, Flat):
        return {"type": "flat", "width": float(s.width)}
    kind = {Ellipse: "ellipse", Lenticular: "lenticular", PowerEllipse: "power_ellipse"}[type(s)]
    keys = {"ellipse": ("width", "height"), "lenticular": ("width", "height", "distortion"),
            "power_ellipse": ("width", "height", "power", "x_offset")}[kind]
    return {"type": kind, **{k: float(getattr(s, k)) for k in keys}}


YARN_KEYS = {"name", "nodes", "interpolation", "periodic", "repeats", "tangents", "ups", "angles",
             "force_in_plane_tangent", "force_node_tangent_in_plane", "fibres", "section",
             "node_sections", "mid_sections", "position_sections", "ramped", "polar"}


def yarn_from_dict(d, where: str) -> Yarn:
    _keys(d, where, YARN_KEYS, {"nodes"})
    given = [k for k in ("section", "node_sections", "position_sections") if k in d]
    if len(given) != 1:
        raise FormatError(f"{where}: give exactly one of section, node_sections, position_sections")
    ramped, polar = bool(d.get("ramped", False)), bool(d.get("polar", False))
    section: ConstantSection | NodeSections | PositionSections
    if "section" in d:
        section = ConstantSection(section_from_dict(d["section"], f"{where}.section"))
    elif "node_sections" in d:
        if not isinstance(d["node_sections"], list):
            raise FormatError(f"{where}.node_sections: expected a list of section tables")
        mids = d.get("mid_sections", [])
        if not isinstance(mids, list) or not all(isinstance(m, dict) and set(m) == {"segment", "t", "section"}
                                                 for m in mids):
            raise FormatError(f"{where}.mid_sections: expected a list of tables with segment, t and section")
        try:
            mid = tuple((int(m["segment"]), float(m["t"]),
                         section_from_dict(m["section"], f"{where}.mid_sections[{k}].section"))
                        for k, m in enumerate(mids))
        except (TypeError, ValueError, OverflowError):
            raise FormatError(f"{where}.mid_sections: segment must be a whole number and t a number") from None
        section = NodeSections(tuple(section_from_dict(s, f"{where}.node_sections[{k}]")
                                     for k, s in enumerate(d["node_sections"])), ramped, polar, mid)
    else:
        ps = d["position_sections"]
        _keys(ps, f"{where}.position_sections", {"positions", "sections"}, {"positions", "sections"})
        if not isinstance(ps["sections"], list):
            raise FormatError(f"{where}.position_sections.sections: expected a list of section tables")
        try:
            section = PositionSections(
                tuple(_array(ps["positions"], f"{where}.position_sections.positions", ())),
                tuple(section_from_dict(s, f"{where}.position_sections.sections[{k}]")
                      for k, s in enumerate(ps["sections"])), ramped, polar)
        except FormatError:
            raise
        except TextileError as e:
            raise FormatError(f"{where}.position_sections: {e}") from None
    opt: dict[str, Any] = {}
    for key, tail in (("tangents", (3,)), ("ups", (3,)), ("repeats", (3,)), ("angles", ())):
        if key in d:
            opt[key] = _array(d[key], f"{where}.{key}", tail)
    for key in ("periodic", "force_in_plane_tangent", "force_node_tangent_in_plane"):
        if key in d:
            if not isinstance(d[key], bool):
                raise FormatError(f"{where}.{key}: expected true or false, got {d[key]!r}")
            opt[key] = d[key]
    if "fibres" in d:
        opt["fibres"] = fibre_data.from_dict(d["fibres"], f"{where}.fibres")
    if "interpolation" in d:
        opt["interpolation"] = d["interpolation"]
    if isinstance(d["nodes"], list):
        check_many(f"{where}.nodes", len(d["nodes"]), MAX_NODES_PER_YARN, FormatError)
    try:
        return Yarn(nodes=_array(d["nodes"], f"{where}.nodes", (3,)), section=section,
                    name=str(d.get("name", "")), **opt)
    except TextileError as e:
        raise FormatError(f"{where}: {e}") from None


def yarn_to_dict(y: Yarn) -> dict:
    d = {"name": y.name, "nodes": y.nodes.tolist(), "interpolation": y.interpolation,
         "periodic": y.periodic, "repeats": y.repeats.tolist()}
    for key in ("tangents", "ups", "angles"):
        if getattr(y, key) is not None:
            d[key] = getattr(y, key).tolist()
    if y.force_in_plane_tangent:
        d["force_in_plane_tangent"] = True
    if y.force_node_tangent_in_plane:
        d["force_node_tangent_in_plane"] = True
    if y.fibres is not None:
        d["fibres"] = y.fibres.as_dict()
    s = y.section
    if isinstance(s, ConstantSection):
        d["section"] = section_to_dict(s.section)
    elif isinstance(s, NodeSections):
        d["node_sections"] = [section_to_dict(x) for x in s.at_nodes]
        if s.mid:
            d["mid_sections"] = [{"segment": k, "t": t, "section": section_to_dict(x)} for k, t, x in s.mid]
    else:
        d["position_sections"] = {"positions": list(s.positions),
                                  "sections": [section_to_dict(x) for x in s.at_positions]}
    if not isinstance(s, ConstantSection):
        d["ramped"], d["polar"] = s.ramped, s.polar
    return d


def textile_from_dict(d: dict, where: str = "model") -> Textile:
    """A Textile from a parsed TOML/JSON description (see the module docstring)."""
    from textile_fenicsx.model.weaves import build

    _keys(d, where, {"name", "weave", "cell", "yarns", "resolution", "fibres", "plies"})
    default_fibres = fibre_data.from_dict(d["fibres"], f"{where}.fibres") if "fibres" in d else None
    resolution = Resolution()
    if "resolution" in d:
        _keys(d["resolution"], f"{where}.resolution", {"spacing", "section_points", "per_segment"})
        try:
            resolution = Resolution(**d["resolution"])
        except TextileError as e:
            raise FormatError(f"{where}.resolution: {e}") from None
    if ("weave" in d) == ("yarns" in d):
        raise FormatError(f"{where}: give either a [weave] table or [cell] with [[yarns]]")
    if "weave" in d:
        w = dict(d["weave"]) if isinstance(d["weave"], dict) else None
        if w is None or "type" not in w:
            raise FormatError(f"{where}.weave: a table with a 'type' (plain, twill, satin, crowfoot_satin, orthogonal)")
        kind = w.pop("type")
        try:
            textile = build(kind, **w)
        except TypeError as e:
            raise FormatError(f"{where}.weave: {e}") from None
        except TextileError as e:
            raise FormatError(f"{where}.weave: {e}") from None
        textile.name = str(d.get("name", kind))
        textile.resolution = resolution
        _give_fibres(textile, default_fibres)
        try:
            textile.check_size()
        except TextileError as e:
            raise FormatError(f"{where}.resolution: {e}") from None
        return textile
    if "cell" not in d:
        raise FormatError(f"{where}: a yarn list needs a [cell] table")
    c = d["cell"]
    _keys(c, f"{where}.cell", {"lx", "ly", "x0", "y0", "z_range", "periodic", "shift"}, {"lx", "ly"})
    try:
        given: dict[str, Any] = {k: (tuple(v) if k == "z_range" else v) for k, v in c.items()}
        cell = Cell(**given)
    except (TextileError, TypeError, OverflowError) as e:
        raise FormatError(f"{where}.cell: {e}") from None
    if not isinstance(d["yarns"], list) or not d["yarns"]:
        raise FormatError(f"{where}.yarns: expected a non-empty list of yarn tables")
    check_many(f"{where}.yarns", len(d["yarns"]), MAX_YARNS, FormatError)
    yarns = [yarn_from_dict(y, f"{where}.yarns[{k}]") for k, y in enumerate(d["yarns"])]
    try:
        sizes = d.get("plies")
        if sizes is not None and (not isinstance(sizes, list) or not sizes
                                  or not all(type(n) is int for n in sizes)):  # (a bool is not a count)
            raise FormatError(f"{where}.plies: expected a list of yarn counts, one per ply, got {sizes!r}")
        textile = Textile(cell, yarns, name=str(d.get("name", "textile")), resolution=resolution,
                          plies=len(sizes) if sizes else 1, ply_sizes=tuple(sizes) if sizes else None)
        _give_fibres(textile, default_fibres)
        textile.check_size()
        return textile
    except FormatError:
        raise
    except TextileError as e:  # the yarns do not make a periodic textile in this cell, or too large
        raise FormatError(f"{where}: {e}") from None


def _give_fibres(textile: Textile, fibres) -> None:
    """The model's `[fibres]` table is the fibre data of every yarn that has none of its own."""
    for y in textile.yarns:
        if y.fibres is None:
            y.fibres = fibres


def textile_to_dict(t: Textile) -> dict:
    c = t.cell
    cell: dict[str, Any] = {"lx": c.lx, "ly": c.ly, "x0": c.x0, "y0": c.y0}
    if c.z_range is not None:
        cell["z_range"] = list(c.z_range)
    if not c.periodic:
        cell["periodic"] = False
    if c.shift:  # a sheared cell's lattice (docs/shear.md)
        cell["shift"] = c.shift
    return {"name": t.name, "cell": {k: (float(v) if not isinstance(v, (list, bool)) else v) for k, v in cell.items()},
            "resolution": {"spacing": t.resolution.spacing, "section_points": t.resolution.section_points,
                           "per_segment": t.resolution.per_segment},
            "yarns": [yarn_to_dict(y) for y in t.yarns]} | _plies_to_dict(t)


def _plies_to_dict(t: Textile) -> dict:
    """A stack's plies: the yarns of each, ply by ply (absent for one ply)."""
    return {} if t.plies == 1 else {"plies": list(t.yarns_per_ply())}


def load_model(path) -> Textile:
    """Read a model: .tg3 (TexGen), .toml or .json (our format)."""
    from textile_fenicsx.io.tg3 import read_tg3

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".tg3":
        return read_tg3(path)
    if suffix not in (".toml", ".json"):
        raise FormatError(f"{path}: unknown model format {suffix!r} (use .tg3, .toml or .json)")
    check_file_size(path)
    try:
        text = path.read_text()
    except OSError as e:
        raise FormatError(f"{path}: cannot read ({e.strerror})") from None
    except UnicodeDecodeError:
        raise FormatError(f"{path}: not a UTF-8 text file") from None
    try:
        data = tomllib.loads(text) if suffix == ".toml" else json.loads(text)
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as e:
        raise FormatError(f"{path}: malformed {suffix[1:].upper()}: {e}") from None
    except RecursionError:
        raise FormatError(f"{path}: nested too deeply") from None
    if not isinstance(data, dict):
        raise FormatError(f"{path}: the top level must be a table/object")
    try:
        return textile_from_dict(data, where=path.name)
    except RecursionError:
        raise FormatError(f"{path}: nested too deeply") from None


def save_model(textile: Textile, path) -> Path:
    """Write the textile in our JSON format, atomically (numbers that read back exactly, compact)."""
    text = json.dumps(textile_to_dict(textile), separators=(",", ":"))
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)
