"""TexGen .tg3 (XML) in (tg3_write.py writes it).

Reading takes any textile TexGen saved with its yarns (2D weaves, orthogonal, layer-to-layer, plain
CTextile...) as a generic yarn list: master nodes, repeats, interpolation, yarn sections, sections
and the CDomainPlanes box. Elements without geometry (fibre distributions, section meshes, a weave's
own pattern description) are skipped; anything else unknown is an error naming it.
"""

import logging
import xml.etree.ElementTree as ET
from dataclasses import replace
from pathlib import Path

import numpy as np

from textile_fenicsx.common.errors import FormatError, TextileError
from textile_fenicsx.common.limits import (
    MAX_NODES,
    MAX_NODES_PER_YARN,
    MAX_POLYGON_POINTS,
    MAX_SIZE,
    MAX_YARNS,
    MIN_LENGTH,
    check_file_size,
    check_many,
)
from textile_fenicsx.model import fibres as fibre_data
from textile_fenicsx.model.coupon import tile
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
from textile_fenicsx.model.textile import Cell, Textile
from textile_fenicsx.model.yarn import ConstantSection, NodeSections, PositionSections, Yarn

log = logging.getLogger(__name__)

INTERPOLATION_IN = {"CInterpolationBezier": "bezier", "CInterpolationCubic": "cubic",
                    "CInterpolationLinear": "linear"}
# Children that carry no geometry of the yarn or describe how a weave textile built its yarns.
IGNORED_YARN_CHILDREN = {"FibreDistribution", "SectionMesh", "SlaveNode", "Mesh"}
# TexGen's stack of plies (AddLayer, NestLayers): its yarns are read ply by ply (Textile.plies)
LAYERED = "CTextileLayered"
# TexGen's 3D weave classes, whose FabricThickness is the thickness the preform is woven to (the
# default mould of the solve); a 2D weave's is its yarns' nominal stack, which the solve may exceed
WOVEN_TO_THICKNESS = {"CTextile3DWeave", "CTextileOrthogonal", "CTextileLayerToLayer", "CTextileAngleInterlock"}
IGNORED_TEXTILE_CHILDREN = {"PatternCell", "XYarns", "YYarns", "XYarnData", "YYarnData", "Properties",
                            "Layer", "Layers", "BinderYarns", "WarpYarns", "WeftYarns"}


def _floats(text, where: str, n: int | None = None) -> np.ndarray:
    if text is None:
        raise FormatError(f"{where}: missing value")
    try:
        v = np.array([float(x) for x in str(text).replace(",", " ").split()])
    except ValueError:
        raise FormatError(f"{where}: not a list of numbers: {text!r}") from None
    if n is not None and len(v) != n:
        raise FormatError(f"{where}: expected {n} numbers, got {text!r}")
    if not np.all(np.isfinite(v)):
        raise FormatError(f"{where}: non-finite number in {text!r}")
    return v


def _attr(el, name: str, where: str, default=None, kind=float):
    text = el.get(name)
    if text is None:
        if default is None:
            raise FormatError(f"{where}: missing attribute {name}")
        return default
    try:
        return kind(float(text)) if kind in (int, bool) else kind(text)
    except (ValueError, OverflowError):
        raise FormatError(f"{where}: attribute {name}={text!r} is not a {kind.__name__}") from None


def _section(el, where: str, depth: int = 0) -> Section:
    """A <Section> element as a Section. depth > 0: a piece of a hybrid section (that deep), which
    may be flat (an ellipse or power ellipse of height 0: TexGen's refine writes a weft's flat half
    so)."""
    kind = el.get("type")
    where = f"{where} {kind}"
    allowed = IGNORED_YARN_CHILDREN | {"PolygonPoint"}
    if kind == "CSectionHybrid":
        allowed = allowed | {"Division", "Section"}
        if depth >= MAX_HYBRID_DEPTH:
            raise FormatError(f"{where}: hybrid sections nested more than {MAX_HYBRID_DEPTH} deep")
    for child in el:
        if child.tag not in allowed:
            raise FormatError(f"{where}: unsupported element <{child.tag}>")
    try:
        if kind in ("CSectionEllipse", "CSectionPowerEllipse") and depth and _attr(el, "Height", where) == 0:
            if _attr(el, "XOffset", where, 0.0) != 0:
                raise FormatError(f"{where}: a flat piece (Height 0) with an XOffset is not supported")
            return Flat(_attr(el, "Width", where))
        if kind == "CSectionEllipse":
            return Ellipse(_attr(el, "Width", where), _attr(el, "Height", where))
        if kind == "CSectionPowerEllipse":
            return PowerEllipse(_attr(el, "Width", where), _attr(el, "Height", where),
                                _attr(el, "Power", where), _attr(el, "XOffset", where, 0.0))
        if kind == "CSectionLenticular":
            if el.get("Radius") is not None and el.get("Offset") is not None:
                r, o = _attr(el, "Radius", where), _attr(el, "Offset", where)
                return Lenticular(2 * np.sqrt(r * r - o * o), 2 * (r - o))
            return Lenticular(_attr(el, "Width", where), _attr(el, "Height", where),
                              _attr(el, "Distortion", where, 0.0))
        if kind == "CSectionPolygon":
            check_many(f"{where}: PolygonPoint elements", len(el.findall("PolygonPoint")), MAX_POLYGON_POINTS,
                       FormatError)
            pts = [_floats(p.get("value"), f"{where} PolygonPoint", 2) for p in el.findall("PolygonPoint")]
            return Polygon(tuple(map(tuple, pts)))
        if kind == "CSectionHybrid":
            return _hybrid(el, where, depth)
    except FormatError:
        raise
    except TextileError as e:
        raise FormatError(f"{where}: {e}") from None
    raise FormatError(f"{where}: unsupported section type {kind!r}")


def _hybrid(el, where: str, depth: int) -> Hybrid:
    """TexGen's CSectionHybrid: <Division Value=...> elements and one <Section> per division. TexGen
    sorts the divisions as it reads them and gives the sections to them in the file's order (its
    CSectionHybrid(TiXmlElement&)): the first section to the smallest division, and so on."""
    divisions = el.findall("Division")
    pieces = el.findall("Section")
    check_many(f"{where}: Division elements", len(divisions), MAX_POLYGON_POINTS, FormatError)
    if len(pieces) != len(divisions) or not divisions:
        raise FormatError(f"{where}: needs one <Section> per <Division>, at least one; has {len(divisions)} "
                          f"divisions and {len(pieces)} sections")
    values = sorted(_attr(d, "Value", f"{where} Division") for d in divisions)
    return Hybrid(tuple(values), tuple(_section(p, f"{where} piece {k}", depth + 1) for k, p in enumerate(pieces)))


def _yarn_section(el, n_nodes: int, where: str):
    kind = el.get("type")
    where = f"{where} YarnSection {kind}"
    ramped = bool(_attr(el, "Ramped", where, 0, int))
    polar = bool(_attr(el, "Polar", where, 0, int))
    if kind == "CYarnSectionConstant":
        sec = el.find("Section")
        if sec is None:
            raise FormatError(f"{where}: no <Section>")
        return ConstantSection(_section(sec, where))
    if kind == "CYarnSectionInterpNode":
        found, mid = {}, []
        for ns in el.findall("NodeSection"):
            k = _attr(ns, "nodeindex", where, kind=int)
            sec = ns.find("Section")
            if sec is None:
                raise FormatError(f"{where}: NodeSection {k} has no <Section>")
            found[k] = _section(sec, f"{where} node {k}")
            for ms in ns.findall("MidNodeSection"):  # TexGen's refine: sections inside segment k
                t = _attr(ms, "t", where)
                inner = ms.find("Section")
                if inner is None or not 0 < t < 1 or k >= n_nodes - 1:
                    raise FormatError(f"{where}: MidNodeSection of node {k} needs a <Section>, 0 < t < 1 and a "
                                      "following node")
                mid.append((k, float(t), _section(inner, f"{where} node {k} mid")))
        if sorted(found) != list(range(n_nodes)):
            raise FormatError(f"{where}: needs one NodeSection per master node 0..{n_nodes - 1}, has {sorted(found)}")
        if len({(k, t) for k, t, _ in mid}) != len(mid):
            raise FormatError(f"{where}: two MidNodeSections at the same place of a segment")
        return NodeSections(tuple(found[k] for k in range(n_nodes)), ramped, polar, tuple(mid))
    if kind == "CYarnSectionInterpPosition":
        items = []
        for ps in el.findall("PositionSection"):
            sec = ps.find("Section")
            if sec is None:
                raise FormatError(f"{where}: PositionSection has no <Section>")
            items.append((_attr(ps, "t", where), _section(sec, where)))
        if not items:
            raise FormatError(f"{where}: no PositionSection")
        items.sort(key=lambda x: x[0])
        return PositionSections(tuple(t for t, _ in items), tuple(s for _, s in items), ramped, polar)
    raise FormatError(f"{where}: unsupported yarn section type {kind!r}")


def _yarn(el, textile_where: str) -> Yarn:
    where = f"{textile_where} Yarn {el.get('index', '?')}"
    known = {"Interpolation", "YarnSection", "Repeat", "MasterNode"} | IGNORED_YARN_CHILDREN
    for child in el:
        if child.tag not in known:
            raise FormatError(f"{where}: unsupported element <{child.tag}>")
    nodes = el.findall("MasterNode")
    check_many(f"{where}: MasterNode elements", len(nodes), MAX_NODES_PER_YARN, FormatError)
    nodes = sorted(nodes, key=lambda n: _attr(n, "index", where, kind=int))
    if len(nodes) < 2:
        raise FormatError(f"{where}: needs at least 2 MasterNode elements, has {len(nodes)}")
    pos = np.array([_floats(n.get("Position"), f"{where} MasterNode {i} Position", 3) for i, n in enumerate(nodes)])

    def per_node(name, default):  # None when no node has the attribute (TexGen's default applies)
        if all(n.get(name) is None for n in nodes):
            return None
        return np.array([_floats(n.get(name), f"{where} MasterNode {i} {name}", len(default))
                         if n.get(name) is not None else default for i, n in enumerate(nodes)])

    interp = el.find("Interpolation")
    if interp is None:
        raise FormatError(f"{where}: no <Interpolation>")
    itype = interp.get("type")
    if itype not in INTERPOLATION_IN:
        raise FormatError(f"{where}: unsupported interpolation type {itype!r}")
    ysec = el.find("YarnSection")
    if ysec is None:
        raise FormatError(f"{where}: no <YarnSection>")
    angles = per_node("Angle", np.zeros(1))
    fibres = fibre_data.from_tg3(el, where)
    try:
        return Yarn(
            nodes=pos,
            section=_yarn_section(ysec, len(pos), where),
            interpolation=INTERPOLATION_IN[itype],
            periodic=bool(_attr(interp, "Periodic", where, 1, int)),
            repeats=np.array([_floats(r.get("value"), f"{where} Repeat", 3)
                              for r in el.findall("Repeat")]).reshape(-1, 3),
            tangents=per_node("Tangent", np.zeros(3)),
            ups=per_node("Up", np.zeros(3)),
            angles=None if angles is None else angles[:, 0],
            force_in_plane_tangent=bool(_attr(interp, "ForceInPlaneTangent", where, 0, int)),
            force_node_tangent_in_plane=bool(_attr(interp, "ForceMasterNodeTangent", where, 0, int)),
            fibres=fibres,
            name=f"yarn {el.get('index', '?')}",
        )
    except FormatError:
        raise
    except TextileError as e:
        raise FormatError(f"{where}: {e}") from None


def _domain(textile_el, yarns: list[Yarn], where: str) -> Cell:
    dom = textile_el.find("Domain")
    if dom is None:
        reps = yarns[0].repeats
        if len(reps) != 2 or abs(reps[0, 1]) > 0 or reps[1, 1] == 0:
            raise FormatError(f"{where}: no <Domain> and no repeats (a1 along x, a2 across it) to define the unit cell")
        try:
            return Cell(float(reps[0, 0]), float(reps[1, 1]), shift=float(reps[1, 0]))
        except TextileError as e:
            raise FormatError(f"{where}: repeats as the unit cell: {e}") from None
    if dom.get("type") != "CDomainPlanes":
        raise FormatError(f"{where}: unsupported domain type {dom.get('type')!r} (only CDomainPlanes)")
    lo: list = [None] * 3  # plane offsets per axis, None until a plane bounds it
    hi: list = [None] * 3
    tilt: list = [None, None]  # the x sides' dx/dy (TexGen's sheared domain leans them along a2)
    for plane in dom.findall("Plane"):
        n = _floats(plane.get("Normal"), f"{where} Domain Plane Normal", 3)
        d = _attr(plane, "d", f"{where} Domain Plane")
        big = np.abs(n) > 1e-12
        if big[0] and big[1] and not big[2]:  # an x side leaning along a2: x = (d - ny y) / nx
            side = 0 if n[0] > 0 else 1
            tilt[side] = -n[1] / n[0]
            (lo if side == 0 else hi)[0] = d / n[0]  # x where the side meets y = 0
            continue
        axis = int(np.argmax(np.abs(n)))
        if np.count_nonzero(big) != 1:
            raise FormatError(f"{where}: Domain plane with normal {n.tolist()} is neither axis-aligned nor an x side "
                              "leaning in the plane (TexGen's sheared domain)")
        if n[axis] > 0:
            lo[axis] = d / n[axis]
        else:
            hi[axis] = d / n[axis]
        if axis == 0:
            tilt[0 if n[axis] > 0 else 1] = 0.0
    if any(v is None for v in lo[:2] + hi[:2]):
        raise FormatError(f"{where}: Domain planes do not bound x and y on both sides")
    if abs(tilt[0] - tilt[1]) > 1e-9 * (1 + abs(tilt[0])):
        raise FormatError(f"{where}: the Domain's x sides are not parallel (dx/dy {tilt[0]:g} and {tilt[1]:g})")
    z_range = (lo[2], hi[2]) if lo[2] is not None and hi[2] is not None else None
    # TexGen repeats yarns by their repeat vectors and clips them by the domain: with no repeats at
    # all, the domain is a coupon with free edges
    periodic = any(len(y.repeats) for y in yarns)
    lx, ly = hi[0] - lo[0], hi[1] - lo[1]
    shift = _shift(yarns, tilt[0] * ly, lx, ly, periodic, where)
    if shift:  # the sheared domain's width is a difference of values printed to 13 digits: the
        # yarns' repeat along x, where it agrees, is the exact one (2e-13 mm apart at 30 degrees)
        along = [r[0] for y in yarns for r in y.repeats if abs(r[1]) == 0 and abs(r[0] - lx) < 1e-9 * lx]
        lx = float(along[0]) if along else lx
    try:
        return Cell(lx, ly, lo[0] + tilt[0] * lo[1], lo[1], z_range, periodic, shift)
    except TextileError as e:
        raise FormatError(f"{where}: Domain: {e}") from None


def _shift(yarns: list[Yarn], leaning: float, lx: float, ly: float, periodic: bool, where: str) -> float:
    """The cell's shift (Cell.shift) [mm]: the x part of the yarns' repeat across x where it leans
    (CShearedTextileWeave2D: (sum of spacings) x (sin, cos) of the shear), else `leaning`, the
    domain's own lean over its height (a sheared domain, or 0 for a box). Both must describe one
    lattice: the lean of a sheared domain is the repeat's, up to whole cells along x."""
    leans = [r for y in yarns for r in y.repeats if abs(r[0]) > 1e-9 * lx and abs(r[1]) > 1e-9 * ly]
    if not leans:
        if leaning and not periodic:
            raise FormatError(f"{where}: a sheared Domain with no repeats (a coupon of a sheared fabric) is not "
                              "supported")
        if leaning and abs(leaning / lx - round(leaning / lx)) > 1e-6:
            raise FormatError(f"{where}: the Domain is sheared ({leaning:g} mm along x over its height) but the yarns "
                              "repeat along x and y: not one lattice")
        return 0.0 if not leaning else float(leaning)
    a2 = leans[0]
    if any(np.abs(r - a2).max() > 1e-6 * max(lx, ly) for r in leans):
        raise FormatError(f"{where}: the yarns repeat by different oblique vectors ({leans[0].tolist()}, ...): a "
                          "sheared cell needs one lattice")
    if abs(a2[1] - ly) > 1e-6 * ly:
        raise FormatError(f"{where}: the yarns repeat by {a2.tolist()} across x, not one Domain height "
                          f"({ly:g} mm) up")
    if leaning and abs((a2[0] - leaning) / lx - round((a2[0] - leaning) / lx)) > 1e-6:
        raise FormatError(f"{where}: the Domain leans {leaning:g} mm along x over its height, the yarns' repeat "
                          f"{a2[0]:g} mm: not one lattice")
    return float(a2[0])


def read_tg3(path, textile: str | None = None) -> Textile:
    """Read a TexGen .tg3 file as a Textile (the named textile, or the only/first one)."""
    path = Path(path)
    check_file_size(path)
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as e:
        raise FormatError(f"{path}: not valid XML ({e})") from None
    except OSError as e:
        raise FormatError(f"{path}: cannot read ({e.strerror})") from None
    if root.tag != "TexGenModel":
        raise FormatError(f"{path}: root element is <{root.tag}>, expected <TexGenModel>")
    textiles = root.findall("Textile")
    if not textiles:
        raise FormatError(f"{path}: no <Textile>")
    if textile is not None:
        textiles = [t for t in textiles if t.get("name") == textile]
        if not textiles:
            raise FormatError(f"{path}: no textile named {textile!r}")
    el = textiles[0]
    where = f"{path.name}: Textile {el.get('name', '?')!r} ({el.get('type', '?')})"
    layered = el.get("type") == LAYERED
    for child in el:
        if child.tag not in {"Domain", "Yarn"} | IGNORED_TEXTILE_CHILDREN | ({"Offset"} if layered else set()):
            raise FormatError(f"{where}: unsupported element <{child.tag}>")
    yarn_els = el.findall("Yarn")
    check_many(f"{where}: Yarn elements", len(yarn_els), MAX_YARNS, FormatError)
    check_many(f"{where}: MasterNode elements of all yarns", len(el.findall("Yarn/MasterNode")), MAX_NODES, FormatError)
    if not yarn_els:
        raise FormatError(f"{where}: the file holds no yarns (saved with OUTPUT_MINIMAL?); "
                          "save it from TexGen with OUTPUT_STANDARD or OUTPUT_FULL")
    def index(y):
        try:
            return int(y.get("index", 0) or 0)
        except ValueError:
            raise FormatError(f"{where}: <Yarn index={y.get('index')!r}> is not a whole number") from None

    yarns = [_yarn(y, where) for y in sorted(yarn_els, key=index)]
    plies, sizes = 1, None
    if layered:  # TexGen's stack of plies: the yarns in place already, listed ply by ply
        indices = [index(y) for y in yarn_els]
        if len(set(indices)) != len(indices):
            raise FormatError(f"{where}: two <Yarn> elements have the same index "
                              f"{sorted({i for i in indices if indices.count(i) > 1})}")
        layers = _layers(el, indices, where)
        at = {i: k for k, i in enumerate(sorted(indices))}  # index -> place among the yarns read
        yarns, plies = [yarns[at[i]] for layer in layers for i in layer], len(layers)
        sizes = tuple(len(layer) for layer in layers)
    # the textile's fibre data: for yarns without their own fibre area (TexGen's CYarn takes the
    # textile's fibre area where its own data gives none, e.g. a fibre count without a diameter)
    default = fibre_data.from_tg3(el, where)
    for y in yarns:
        if y.fibres is None or (default is not None and y.fibres.fibre_area() is None):
            y.fibres = default
    cell = _domain(el, yarns, where)
    if layered:
        yarns, sizes = _plies_over_cell(yarns, sizes or (len(yarns) // plies,) * plies, cell, where)
        cell = _around_yarns(cell, yarns, where)
    try:
        woven_to = _woven_to(el, where)
        model = Textile(cell=cell, yarns=yarns, name=el.get("name") or path.stem, thickness=woven_to, plies=plies,
                        ply_sizes=sizes)
        model.check_size()
        return model
    except FormatError:
        raise
    except TextileError as e:  # the yarns do not make a periodic textile in this domain, or too large
        raise FormatError(f"{where}: {e}") from None


def _layers(el, indices: list[int], where: str) -> list[list[int]]:
    """A CTextileLayered's plies: each <Layer>'s yarn indices (every yarn in exactly one). Its
    <Offset> elements (one per layer) record how far AddLayer moved each ply in the plane; the
    yarns are saved moved, so they are checked, not applied."""
    layers = []
    for k, layer in enumerate(el.findall("Layer"), start=1):
        members = []
        for y in layer:
            if y.tag != "Yarn":
                raise FormatError(f"{where}: <Layer> {k}: unsupported element <{y.tag}>")
            text = y.get("yarnindex")
            if text is None or not text.strip().isdigit():
                raise FormatError(f"{where}: <Layer> {k}: yarnindex={text!r} is not a yarn index (a whole number)")
            members.append(int(text))
        if not members:
            raise FormatError(f"{where}: <Layer> {k} holds no yarns")
        layers.append(members)
    listed = sorted(i for layer in layers for i in layer)
    if listed != sorted(indices):
        missing, extra = sorted(set(indices) - set(listed)), sorted(set(listed) - set(indices))
        repeated = sorted({i for i in listed if listed.count(i) > 1})
        raise FormatError(f"{where}: the <Layer> elements must list every yarn once (missing {missing}, not a yarn "
                          f"{extra}, listed more than once {repeated})")
    offsets = el.findall("Offset")
    if offsets and len(offsets) != len(layers):
        raise FormatError(f"{where}: {len(offsets)} <Offset> elements for {len(layers)} layers")
    for k, o in enumerate(offsets, start=1):
        _floats(o.get("value"), f"{where}: <Offset> {k}", 2)
    return layers


def _ply_period(ply: list[Yarn]) -> tuple[float, float] | None:
    """The cell a ply repeats by, (lx, ly) [mm]: its yarns' two axis-aligned repeat vectors, the same
    for every yarn of the ply (TexGen's 2D weaves); None for a ply with other repeats (left to the
    stack's own periodicity check)."""
    reps = {tuple(np.round(y.repeats, 9).ravel()) for y in ply}
    if len(reps) != 1:
        return None
    r = ply[0].repeats
    if len(r) != 2 or abs(r[0, 1]) + abs(r[1, 0]) + abs(r[0, 2]) + abs(r[1, 2]) > 0 or min(r[0, 0], r[1, 1]) <= 0:
        return None
    return float(r[0, 0]), float(r[1, 1])


def _plies_over_cell(yarns: list[Yarn], sizes: tuple[int, ...], cell: Cell,
                     where: str) -> tuple[list[Yarn], tuple[int, ...]]:
    """Each ply's yarns once per cell of the stack. TexGen repeats every yarn by its own repeat
    vectors, so a ply whose cell is a whole fraction of the stack's (a 4 x 4 mm plain ply on an 8 x
    8 mm twill) fills it with its copies: the ply is tiled over the stack's cell (coupon.tile: each
    yarn continued over the periods the cell holds, in as many parallel copies as it has room for,
    named "<yarn> [i,j]"). Plies that repeat by the stack's cell are kept as read. The plies' sizes
    after tiling are returned with the yarns."""
    out: list[Yarn] = []
    counts = []
    start = 0
    for k, n in enumerate(sizes):
        ply = yarns[start:start + n]
        start += n
        period = _ply_period(ply)
        if period is None or (np.isclose(period[0], cell.lx) and np.isclose(period[1], cell.ly)):
            out += ply
            counts.append(n)
            continue
        nx, ny = cell.lx / period[0], cell.ly / period[1]
        if min(nx, ny) < 1 - 1e-9 or abs(nx - round(nx)) > 1e-6 or abs(ny - round(ny)) > 1e-6:
            raise FormatError(f"{where}: ply {k + 1} repeats every {period[0]:g} x {period[1]:g} mm, which does not "
                              f"divide the stack's cell of {cell.lx:g} x {cell.ly:g} mm (its <Domain>): the stack "
                              "is not periodic in that cell; make the domain a common multiple of the plies' cells")
        try:
            own = Textile(Cell(period[0], period[1], cell.x0, cell.y0, cell.z_range), ply)
            tiled = tile(own, int(round(nx)), int(round(ny))).yarns
        except TextileError as e:
            raise FormatError(f"{where}: ply {k + 1}: {e}") from None
        log.info("%s: ply %d repeats every %g x %g mm, %d x %d times in the stack's cell: its %d yarns become %d",
                 where, k + 1, period[0], period[1], round(nx), round(ny), n, len(tiled))
        out += tiled
        counts.append(len(tiled))
    return out, tuple(counts)


def _around_yarns(cell: Cell, yarns: list[Yarn], where: str) -> Cell:
    """A stack's cell with its z range (the <Domain>'s z planes) opened to hold every yarn whole:
    the plies are the model, and the domain given to the stack (assigned before NestLayers, or for
    one ply) can cut the upper plies' crowns, which the metrics would clip away from the input and
    not from the corrected model (whose z range holds its yarns: correction/correct.py). The yarns
    reach the master nodes' z -+ half the tallest section [mm]; where that passes a plane, the z
    range is opened to it, by the margin the correction gives its own (a whole section height)."""
    if cell.z_range is None:
        return cell
    z = np.concatenate([y.nodes[:, 2] for y in yarns])
    tallest = max(s.height for y in yarns for s in y.section.sections())
    z0, z1 = cell.z_range
    if float(z.min()) - tallest / 2 >= z0 - 1e-9 and float(z.max()) + tallest / 2 <= z1 + 1e-9:
        return cell
    lo, hi = float(z.min()) - tallest, float(z.max()) + tallest
    log.warning("%s: the domain's z planes (%.4g to %.4g mm) cut the plies' yarns (%.4g to %.4g mm); the stack is "
                "read whole, its z range opened to them", where, z0, z1, lo, hi)
    return replace(cell, z_range=(min(z0, lo), max(z1, hi)))


def _woven_to(el, where: str) -> float | None:
    """A 3D weave's FabricThickness [mm], None for other textiles, or where it is no thickness
    (TexGen leaves it unset, e.g. 2e-314, in an orthogonal weave built without SetThickness)."""
    if el.get("type") not in WOVEN_TO_THICKNESS or el.get("FabricThickness") is None:
        return None
    value = _attr(el, "FabricThickness", where)
    if not MIN_LENGTH <= value <= MAX_SIZE:
        log.warning("%s: FabricThickness=%s is not a thickness; the fabric has no default mould", where,
                    el.get("FabricThickness"))
        return None
    return value
