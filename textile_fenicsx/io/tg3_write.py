"""TexGen .tg3 (XML) out (tg3.py reads it).

Writing produces a plain CTextile that TexGen 3.14 reads back without rebuilding it (the facts in
reference/README.md): mandatory yarn attributes, CDomainPlanes, and each yarn's own
interpolation and sections (per-node polygons for corrected yarns).
"""

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from textile_fenicsx.common.errors import TextileError
from textile_fenicsx.common.files import atomic_path
from textile_fenicsx.io.tg3 import INTERPOLATION_IN, LAYERED
from textile_fenicsx.model import fibres as fibre_data
from textile_fenicsx.model.sections import Ellipse, Flat, Hybrid, Lenticular, Polygon, PowerEllipse, Section
from textile_fenicsx.model.textile import Textile
from textile_fenicsx.model.yarn import ConstantSection, NodeSections, Yarn

INTERPOLATION_OUT = {v: k for k, v in INTERPOLATION_IN.items()}


def _num(v) -> str:
    """Numbers as TexGen writes them, each in the shortest form that reads back to the same double
    (a model written and read again is identical)."""
    return ", ".join(map(repr, np.atleast_1d(np.asarray(v, float)).tolist()))


def _section_element(parent, sec: Section, n_points: int):
    el = ET.SubElement(parent, "Section")
    if isinstance(sec, Ellipse):
        el.attrib.update(type="CSectionEllipse", Width=_num(sec.width), Height=_num(sec.height))
    elif isinstance(sec, PowerEllipse):
        el.attrib.update(type="CSectionPowerEllipse", Width=_num(sec.width), Height=_num(sec.height),
                         Power=_num(sec.power), XOffset=_num(sec.x_offset))
    elif isinstance(sec, Lenticular):
        el.attrib.update(type="CSectionLenticular", Width=_num(sec.width), Height=_num(sec.height),
                         Distortion=_num(sec.distortion))
    elif isinstance(sec, Polygon):
        el.attrib.update(type="CSectionPolygon", RetainPoints="0")
        for p in sec.vertices:
            ET.SubElement(el, "PolygonPoint", value=_num(p))
    elif isinstance(sec, Flat):  # TexGen's flat half of a hybrid: an ellipse of height 0
        el.attrib.update(type="CSectionEllipse", Width=_num(sec.width), Height=_num(0.0))
    elif isinstance(sec, Hybrid):
        el.attrib.update(type="CSectionHybrid")
        for d in sec.divisions:
            ET.SubElement(el, "Division", Value=_num(d))
        for p in sec.pieces:
            _section_element(el, p, n_points)
    else:
        raise TextileError(f"cannot write section of type {type(sec).__name__}")
    return el


def _section_points_for(yarn: Yarn) -> int:
    # TexGen resamples polygons to NumSectionPoints; ~4x the vertex count keeps corners (README).
    polys = [s for s in yarn.section.sections() if isinstance(s, Polygon)]
    return max([40] + [4 * len(p.vertices) for p in polys])


def _x_sides(c) -> tuple:
    """The domain's two planes across x: x = x0 and x = x0 + lx, or for a sheared cell TexGen's
    sheared domain (CShearedTextileWeave2D::GetDefaultDomain(true)): the parallelogram's sides along
    a2 = (shift, ly) through (x0, y0) and (x0 + lx, y0), normals (cos g, -sin g, 0) and its opposite."""
    if not c.shift:
        return (((1, 0, 0), c.x0), ((-1, 0, 0), -(c.x0 + c.lx)))
    g = np.arctan2(c.shift, c.ly)
    cos, sin = float(np.cos(g)), float(np.sin(g))
    return (((cos, -sin, 0), c.x0 * cos - c.y0 * sin), ((-cos, sin, 0), -(c.x0 + c.lx) * cos + c.y0 * sin))


def tg3_tree(textile: Textile) -> ET.ElementTree:
    """The XML tree of a plain CTextile holding the textile's yarns as they are; a stack of plies
    as TexGen's CTextileLayered (its yarns in place, each ply's listed in a <Layer>)."""
    root = ET.Element("TexGenModel", version="3.14.0")
    tex = ET.SubElement(root, "Textile", name=textile.name, type="CTextile" if textile.plies == 1 else LAYERED,
                        GeometryScale="mm")
    c = textile.cell
    z0, z1 = c.z_range if c.z_range is not None else _z_extent(textile)
    dom = ET.SubElement(tex, "Domain", type="CDomainPlanes")
    for normal, d in (_x_sides(c) + (((0, 1, 0), c.y0), ((0, -1, 0), -(c.y0 + c.ly)), ((0, 0, 1), z0),
                                      ((0, 0, -1), -z1))):
        ET.SubElement(dom, "Plane", Normal=_num(normal), d=_num(d))
    for i, y in enumerate(textile.yarns):
        n_sec = _section_points_for(y)
        yel = ET.SubElement(tex, "Yarn", index=str(i), NumSlaveNodes=str(max(40, 4 * len(y.nodes))),
                            NumSectionPoints=str(n_sec), NeedsBuilding="7")
        if y.fibres is not None:
            yel.attrib.update(fibre_data.tg3_attributes(y.fibres))
        ET.SubElement(yel, "Interpolation", type=INTERPOLATION_OUT[y.interpolation],
                      Periodic=str(int(y.periodic)), ForceInPlaneTangent=str(int(y.force_in_plane_tangent)),
                      ForceMasterNodeTangent=str(int(y.force_node_tangent_in_plane)))
        sec = y.section
        if isinstance(sec, ConstantSection):
            ys = ET.SubElement(yel, "YarnSection", type="CYarnSectionConstant", ConstMesh="1")
            _section_element(ys, sec.section, n_sec)
        elif isinstance(sec, NodeSections):
            ys = ET.SubElement(yel, "YarnSection", type="CYarnSectionInterpNode",
                               Ramped=str(int(sec.ramped)), Polar=str(int(sec.polar)))
            for k, s in enumerate(sec.at_nodes):
                node = ET.SubElement(ys, "NodeSection", nodeindex=str(k))
                _section_element(node, s, n_sec)
                for segment, t, x in sec.mid:
                    if segment == k:
                        _section_element(ET.SubElement(node, "MidNodeSection", nodeindex=str(k), t=_num(t)), x,
                                         n_sec)
        else:
            ys = ET.SubElement(yel, "YarnSection", type="CYarnSectionInterpPosition",
                               Ramped=str(int(sec.ramped)), Polar=str(int(sec.polar)))
            for t, s in zip(sec.positions, sec.at_positions):
                _section_element(ET.SubElement(ys, "PositionSection", t=_num(t)), s, n_sec)
        for r in y.repeats:
            ET.SubElement(yel, "Repeat", value=_num(r))
        for k, p in enumerate(y.nodes):
            node = ET.SubElement(yel, "MasterNode", index=str(k), Position=_num(p))
            if y.tangents is not None:
                node.set("Tangent", _num(y.tangents[k]))
            if y.ups is not None:
                node.set("Up", _num(y.ups[k]))
            if y.angles is not None:
                node.set("Angle", _num(y.angles[k]))
    if textile.plies > 1:
        from textile_fenicsx.model.plies import ply_of

        tex.set("Resolution", "40")
        ply = np.array(ply_of(textile))
        for k in range(textile.plies):
            layer = ET.SubElement(tex, "Layer")
            for i in np.flatnonzero(ply == k):
                ET.SubElement(layer, "Yarn", yarnindex=str(i))
    ET.indent(root, space="    ")
    return ET.ElementTree(root)


def _z_extent(textile: Textile) -> tuple[float, float]:
    z = np.concatenate([textile.triangles(i)[..., 2].ravel() for i in range(len(textile.yarns))])
    pad = 0.05 * (z.max() - z.min())
    return float(z.min() - pad), float(z.max() + pad)


def write_tg3(textile: Textile, path) -> Path:
    """Write the textile as a generic TexGen .tg3, atomically."""
    tree = tg3_tree(textile)
    with atomic_path(path) as tmp:
        tree.write(tmp, encoding="utf-8", xml_declaration=True)
    return Path(path)
