#!/usr/bin/env python3
"""Build the robustness-sweep family of fabrics with TexGen's own classes (PyPI pytexgen 1.2.1).

Runs under the Python that bench/texgen_env.sh prints (never imports textile_fenicsx):

    PY=$(bench/texgen_env.sh)
    $PY bench/make_fabrics.py [--out DIR] [--only NAME ...] [--list]

Each model is built by TexGen (constructor, pattern and yarn setters, AssignDefaultDomain), added
with AddTextile(name, textile, True) and saved with SaveToXML(DIR/NAME.tg3, name, OUTPUT_STANDARD);
DIR (default reference/fabrics of this repository) also gets index.json: for every file the TexGen
calls that made it (as Python lines, in order), the parameters behind them, and what TexGen reports
about the built textile (type, yarn counts, domain box, section types, refine flag), plus the file's
size and sha256. Everything is fixed in this script: re-running gives byte-identical files.
--only rebuilds some models and leaves index.json alone; --list prints the names.

The family (65 models: 49, and 16 stacks of plies):
  2D weaves, CTextileWeave2D(n, n, spacing, thickness, refine), pattern by SwapPosition(x, y):
    every pattern at a middle setting (spacing 2.0, width/spacing 0.9, height/width 0.2, ellipse,
    refine off): plain, 2/2 twill, 3/1 twill, 4-harness crowfoot satin, 5- and 8-harness satin,
    2x2 and 3x3 basket;
    then one factor at a time on the plain weave and the 4-harness satin: width/spacing (0.6, 0.8
    [plain only], 0.98), height/width (0.1, 0.3), section (CSectionLenticular, CSectionPowerEllipse
    power 0.6 and 1.5, CSectionPolygon rounded rectangle), rectangular cell (spacing 2.0 along x,
    3.0 along y), unbalanced yarns (x yarns w/s 0.9 h/w 0.2, y yarns w/s 0.7 h/w 0.3), TexGen's
    refine on (and, for the plain weave, refine on at width/spacing 0.98).
    Sections other than TexGen's default ellipse are given after the weave is built, to every yarn:
    yarn.AssignSection(CYarnSectionConstant(section)) (the weave is then not rebuilt: the saved file
    keeps them and TexGen reads them back as saved). Refine on keeps TexGen's own (refined) sections.
  3D weaves, dimensions of reference/models/ortho (warp w 3.6 h 0.35 spacing 3.8 power 0.6, weft
    w 2.58 h 0.3 spacing 2.8 power 0.6, binder w 1.375 h 0.16 spacing 1.4 power 0.8):
    CTextileOrthogonal: the reference model (2 warp, 3 weft layers), 3 warp / 4 weft layers, and
    larger elliptical binders (w 1.0 h 0.3 spacing 1.2 power 1.0);
    CTextileLayerToLayer: 2/3 layers with 3 binder layers, pattern 0011; 3/4 layers with 2 binder
    layers, pattern 0121; 2/3 layers with 3 binder layers over 6 wefts, pattern 000111;
    CTextileAngleInterlock: 2/3 layers over 6 wefts, 3/4 layers over 8 wefts.
    TexGen's 3D weaves leave FabricThickness uninitialised (the file would change from run to run),
    so each gets SetThickness(default domain height / 1.1) last; no yarn or domain changes.
  3D weaves with fibre data (FIBRES: TexGen has none by default, its setters take SI units, so these
  are typical carbon tows in those units: 7e-06 m fibres of 1800 kg/m^3, 12k warp and weft tows of
  0.0008 kg/m, 3k binders of 0.0002 kg/m), set per yarn type as TexGen's 3D weave wizard does
  (SetFibreDiameter, SetFibresPerYarn, SetFibreDensity, SetYarnLinearDensity) on the orthogonal
  weaves; the layer-to-layer and angle-interlock classes drop per-type data (their yarns never get
  it), so theirs is set as the GUI's property pages do: the tow's on the textile (the default of
  every yarn without its own) and the binder tow's on each binder yarn; refine on and off:
    CTextileOrthogonal, refine off (the reference dimensions), and refine on (bRefine True) with a
    target thickness, in the wizard's order (SetThickness, fibre data, SetMaxVolFraction(0.78) before
    the binder swaps; AssignDefaultDomain, then SetDomainZValues): 2 warp / 3 weft layers at their
    nominal 1.92 mm (the outer wefts become hybrid sections: a power-ellipse half and a flat half),
    1.8 mm and 1.7 mm (the warps become polygons with two mid-node sections per segment; TexGen says
    "Can't reduce outer weft and binder to fit without exceeding max Vf" and saves it all the same),
    and 3 warp / 4 weft layers at 2.4 mm (nominal 2.57);
    CTextileLayerToLayer (2/3 layers, 3 binder layers, pattern 0011) and CTextileAngleInterlock
    (2/3 layers over 6 wefts): TexGen has no refine for these (the layer-to-layer constructor's bool
    is bShapeBinders; SetThickness only records the number), so refine off only.
    CTextile3DWeave, the base class, is no builder of its own: pytexgen 1.2.1 has no BuildTextile for
    it and crashes (segmentation fault) when it builds one; its bRefine is read by CTextileOrthogonal
    alone.
  Binders thicker than the 0.22 mm gap between weft columns (their physics is issue 27's item 4): the
  orthogonal weave with the reference binder 0.3 mm high (1.375 x 0.3, power 0.8), and the
  layer-to-layer weave (pattern 0011) with the larger elliptical binder (1.0 x 0.3, power 1.0).
  Stacks of plies, TexGen's CTextileLayered (issue 74): each ply a 2D weave of the middle setting
  (plain, 2/2 twill or 4-harness satin, built as above), added with AddLayer(ply, XYZ(dx, dy, k t))
  (t: the plies' FabricThickness, 0.72 mm), the in-plane offset (dx, dy) given in yarn spacings
  (2.0 mm): 0.25, 0.5, 0.75 and 1.3 spacings, negative ones, in x, y or both; 2, 3 and 4 plies;
  plain, twill and satin plies, and mixed (a plain ply, 4 x 4 mm, over an 8 x 8 mm twill or satin).
  The domain, AssignDomain(CDomainPlanes(...)): the largest ply's default domain in plan (TexGen's,
  a half spacing before the origin), in z from 5 % of t below the first ply to 5 % above the last.
  Most are nested by TexGen (NestLayers, which lowers each ply onto the one below and the domain's
  top with them); a few are not (the plies then rest one fabric thickness apart).
Names: x yarns run along x (TexGen's X yarns, spaced in y), y yarns along y. "w" is width/spacing,
"h" height/width; "s2x3" a cell with y yarns 2.0 apart along x and x yarns 3.0 apart along y.
"""

import argparse
import hashlib
import json
import math
import os
import re
import sys
import xml.etree.ElementTree as ET

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OUT = os.path.join(REPO, "reference", "fabrics")
SPACING = 2.0  # 2D weaves: yarn spacing of the middle setting [mm]

# 2D patterns: (n, cells to swap). Cell (x, y): TexGen's SwapPosition(x, y).
PATTERNS = {
    "plain": (2, [(0, 0), (1, 1)]),
    "twill22": (4, [(x, y) for y in range(4) for x in range(4) if (x - y) % 4 in (0, 1)]),
    "twill31": (4, [(x, y) for y in range(4) for x in range(4) if (x - y) % 4 == 0]),
    "satin4": (4, [(0, 0), (1, 1), (2, 3), (3, 2)]),  # crowfoot, as reference/models/satin4
    "satin5": (5, [(i, 2 * i % 5) for i in range(5)]),  # move 2
    "satin8": (8, [(i, 3 * i % 8) for i in range(8)]),  # move 3
    "basket2": (4, [(x, y) for y in range(4) for x in range(4) if (x // 2 + y // 2) % 2 == 0]),
    "basket3": (6, [(x, y) for y in range(6) for x in range(6) if (x // 3 + y // 3) % 2 == 0]),
}

# 3D weaves: dimensions of reference/models/ortho
WARP = dict(width=3.6, height=0.35, spacing=3.8, power=0.6)
WEFT = dict(width=2.58, height=0.3, spacing=2.8, power=0.6)
BINDER = dict(width=1.375, height=0.16, spacing=1.4, power=0.8)
THICK_BINDER = dict(width=1.0, height=0.3, spacing=1.2, power=1.0)  # thicker than the gap between weft columns
# Fibre data of the 3D weaves "with fibres", in TexGen's default units (those its setters assume):
# typical carbon, 7 um fibres of 1800 kg/m^3, 12k tows (0.8 g/m) for warps and wefts, 3k (0.2 g/m) for
# binders, so that every yarn's fibre fraction is physical (warp 0.42, weft 0.68, binder 0.62)
FIBRES = dict(diameter_m=7e-06, density_kg_m3=1800.0,
              per_yarn=dict(warp=12000, weft=12000, binder=3000),
              linear_density_kg_m=dict(warp=0.0008, weft=0.0008, binder=0.0002))
MAX_VOLUME_FRACTION = 0.78  # TexGen's default for refine (the wizard's too)


def num(x):
    """A float rounded to 10 significant digits (clean values in calls, names and the index)."""
    return float(f"{x:.10g}")


def fmt(v):
    if isinstance(v, bool) or v is None:
        return repr(v)
    if isinstance(v, float):
        return repr(num(v))
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(fmt(x) for x in v) + "]"
    return repr(v)


class Recorder:
    """Calls methods of a TexGen object and writes each call down as a Python line."""

    def __init__(self, obj, var, calls):
        self._obj, self._var, self._calls = obj, var, calls

    def __getattr__(self, name):
        method = getattr(self._obj, name)

        def call(*args):
            self._calls.append(f"{self._var}.{name}({', '.join(fmt(a) for a in args)})")
            return method(*args)

        return call


# ---- the family ---------------------------------------------------------------------------------

def weave_spec(pattern, ws=0.9, hw=0.2, section=("ellipse",), cell=(SPACING, SPACING), y_yarns=None,
               refine=False):
    """A 2D weave. ws, hw: width/spacing and height/width of the x yarns (and the y yarns unless
    y_yarns = (ws, hw) is given); cell = (spacing of the y yarns along x, of the x yarns along y)."""
    n, swaps = PATTERNS[pattern]
    ys = y_yarns or (ws, hw)
    sx, sy = cell
    x_w = num(ws * sy)
    y_w = num(ys[0] * sx)
    x = dict(spacing=num(sy), width=x_w, height=num(hw * x_w), width_over_spacing=ws, height_over_width=hw)
    y = dict(spacing=num(sx), width=y_w, height=num(ys[1] * y_w), width_over_spacing=ys[0],
             height_over_width=ys[1])
    kind = section[0]
    sec = dict(type={"ellipse": "CSectionEllipse", "lenticular": "CSectionLenticular",
                     "powerellipse": "CSectionPowerEllipse", "polygon": "CSectionPolygon"}[kind])
    label = kind
    if kind == "powerellipse":
        sec["power"] = section[1]
        label = f"powerellipse{section[1]:g}"
    if kind == "polygon":
        sec["shape"] = "rounded rectangle of the yarn's width and height, corner radius 0.4 height, 18 points"
    if kind == "ellipse" and not refine:
        sec["assigned"] = "TexGen's own (the weave's default ellipse)"
    elif kind == "ellipse":
        sec["assigned"] = "TexGen's own (refined by the weave)"
    else:
        sec["assigned"] = "after building, to every yarn: AssignSection(CYarnSectionConstant(...))"
    name = pattern
    if cell != (SPACING, SPACING):
        name += f"_s{sx:g}x{sy:g}"
    name += f"_w{ws:g}" + (f"-{ys[0]:g}" if y_yarns else "")
    name += f"_h{hw:g}" + (f"-{ys[1]:g}" if y_yarns else "")
    name += "_" + label + ("_refine" if refine else "")
    return dict(name=name, kind="weave2d", family="2D weave", pattern=pattern, n=n, swaps=swaps,
                x_yarns=x, y_yarns=y, thickness=num(x["height"] + y["height"]), section=sec,
                refine=refine)


def family():
    specs = [weave_spec(p) for p in PATTERNS]
    for pattern in ("plain", "satin4"):
        for ws in ((0.6, 0.8, 0.98) if pattern == "plain" else (0.6, 0.98)):
            specs.append(weave_spec(pattern, ws=ws))
        for hw in (0.1, 0.3):
            specs.append(weave_spec(pattern, hw=hw))
        for section in (("lenticular",), ("powerellipse", 0.6), ("powerellipse", 1.5), ("polygon",)):
            specs.append(weave_spec(pattern, section=section))
        specs.append(weave_spec(pattern, cell=(2.0, 3.0)))
        specs.append(weave_spec(pattern, y_yarns=(0.7, 0.3)))
        specs.append(weave_spec(pattern, refine=True))
    specs.append(weave_spec("plain", ws=0.98, refine=True))

    def ortho(name, layers, binder=BINDER, note="", fibres=False, refine=False, thickness=None):
        return dict(name=name, kind="orthogonal", family="3D orthogonal", nx=4, ny=4, layers=layers,
                    warp=WARP, weft=WEFT, binder=binder, warp_ratio=1, binder_ratio=1, refine=refine,
                    # binders are x yarns 1 and 3; swapped to the bottom at these weft columns
                    binder_swaps=[(1, 1), (3, 1), (0, 3), (2, 3)], note=note,
                    **_fibre_options(fibres, refine, thickness))

    specs += [
        ortho("ortho_w2f3", (2, 3), note="the calls of reference/models/ortho.api.txt"),
        ortho("ortho_w3f4", (3, 4), note="one more warp and weft layer"),
        ortho("ortho_w2f3_binder1.0x0.3", (2, 3), THICK_BINDER, note="larger, elliptical binders"),
    ]

    def l2l(name, layers, binder_layers, offsets, note, binder=BINDER, fibres=False):
        ny = len(offsets[0])
        return dict(name=name, kind="layertolayer", family="3D layer-to-layer", nx=4, ny=ny, layers=layers,
                    binder_layers=binder_layers, warp=WARP, weft=WEFT, binder=binder, warp_ratio=1,
                    binder_ratio=1, binder_offsets={1: offsets[0], 3: offsets[1]}, note=note,
                    **_fibre_options(fibres, False, None))

    specs += [
        l2l("l2l_w2f3_b3_0011", (2, 3), 3, [[0, 0, 1, 1], [1, 1, 0, 0]],
            "3 stacked binders, each between two neighbouring weft layers"),
        l2l("l2l_w3f4_b2_0121", (3, 4), 2, [[0, 1, 2, 1], [2, 1, 0, 1]],
            "2 stacked binders, each spanning three weft layers"),
        l2l("l2l_w2f3_b3_000111", (2, 3), 3, [[0, 0, 0, 1, 1, 1], [1, 1, 1, 0, 0, 0]],
            "as l2l_w2f3_b3_0011 over 6 wefts (longer floats)"),
    ]

    def ai(name, layers, ny, tops, note, fibres=False):
        return dict(name=name, kind="angleinterlock", family="3D angle interlock", nx=4, ny=ny, layers=layers,
                    warp=WARP, weft=WEFT, binder=BINDER, warp_ratio=1, binder_ratio=1, binder_tops=tops,
                    note=note, **_fibre_options(fibres, False, None))

    specs += [
        ai("angleinterlock_w2f3_y6", (2, 3), 6, [(0, 1), (3, 3)],
           "through the thickness: binder x yarns 1 and 3 top at weft columns 0 and 3"),
        ai("angleinterlock_w3f4_y8", (3, 4), 8, [(0, 1), (4, 3)],
           "through the thickness: binder x yarns 1 and 3 top at weft columns 0 and 4"),
    ]

    # with fibre data, refine off and on (issue 27, item 1)
    specs += [
        ortho("ortho_w2f3_fibres", (2, 3), note="ortho_w2f3 with fibre data", fibres=True),
        ortho("ortho_w2f3_fibres_refine_t1.92", (2, 3), fibres=True, refine=True, thickness=1.92,
              note="refine at the nominal thickness: hybrid outer wefts"),
        ortho("ortho_w2f3_fibres_refine_t1.8", (2, 3), fibres=True, refine=True, thickness=1.8,
              note="refine to 1.8 mm: hybrid outer wefts, power-ellipse binders"),
        ortho("ortho_w2f3_fibres_refine_t1.7", (2, 3), fibres=True, refine=True, thickness=1.7,
              note="refine to 1.7 mm: polygon warps with two mid-node sections per segment (TexGen: "
                   "\"Can't reduce outer weft and binder to fit without exceeding max Vf\")"),
        ortho("ortho_w3f4_fibres_refine_t2.4", (3, 4), fibres=True, refine=True, thickness=2.4,
              note="3 warp / 4 weft layers refined to 2.4 mm (nominal 2.57)"),
        # refined thinner than their yarns stack: pressed to it by --mould auto (issue 74)
        ortho("ortho_w2f3_fibres_refine_t1.6", (2, 3), fibres=True, refine=True, thickness=1.6,
              note="refine to 1.6 mm, thinner than the yarns stack"),
        ortho("ortho_w2f3_fibres_refine_t1.5", (2, 3), fibres=True, refine=True, thickness=1.5,
              note="refine to 1.5 mm, thinner than the yarns stack"),
        ortho("ortho_w3f4_fibres_refine_t2.2", (3, 4), fibres=True, refine=True, thickness=2.2,
              note="3 warp / 4 weft layers refined to 2.2 mm, thinner than the yarns stack"),
        l2l("l2l_w2f3_b3_0011_fibres", (2, 3), 3, [[0, 0, 1, 1], [1, 1, 0, 0]],
            "l2l_w2f3_b3_0011 with fibre data (TexGen has no refine for layer-to-layer weaves)", fibres=True),
        ai("angleinterlock_w2f3_y6_fibres", (2, 3), 6, [(0, 1), (3, 3)],
           "angleinterlock_w2f3_y6 with fibre data (TexGen has no refine for angle interlocks)", fibres=True),
    ]
    # binders thicker than the gap between weft columns (issue 27, item 4)
    specs += [
        ortho("ortho_w2f3_binder1.375x0.3", (2, 3), dict(BINDER, height=0.3),
              note="the reference binder 0.3 mm high, against a 0.22 mm gap between weft columns"),
        l2l("l2l_w2f3_b3_0011_binder1.0x0.3", (2, 3), 3, [[0, 0, 1, 1], [1, 1, 0, 0]],
            "l2l_w2f3_b3_0011 with the larger, elliptical binders of ortho_w2f3_binder1.0x0.3",
            binder=THICK_BINDER),
    ]
    specs += stack_family()
    return specs


def stack_spec(plies, nest=True, note=""):
    """A stack of plies (TexGen's CTextileLayered): plies = [(pattern, dx, dy), ...], the first at
    (0, 0), each ply a weave_spec(pattern) moved by (dx, dy) yarn spacings in the plane. nest: TexGen's
    NestLayers after the domain is assigned."""
    layers = [dict(weave=weave_spec(p), pattern=p, offset_spacings=[num(dx), num(dy)],
                   offset=[num(dx * SPACING), num(dy * SPACING)]) for p, dx, dy in plies]
    name = "stack_" + "_".join(p for p, _, _ in plies) + "".join(f"_{dx:g}x{dy:g}" for _, dx, dy in plies[1:])
    return dict(name=name + ("" if nest else "_apart"), kind="layered", family="stack of plies", layers=layers,
                nest=nest, note=note)


def stack_family():
    """The stacks of plies (issue 74): offsets at and beyond a spacing, negative ones, 2-4 plies,
    plain, twill and satin plies, and mixed weaves."""
    half = [("plain", 0, 0), ("plain", 0.5, 0)]
    specs = [stack_spec(half, note="the plain stack moved by half a spacing of issue 74"),
             stack_spec(half, nest=False, note="as the first, not nested: the plies one fabric thickness apart")]
    for dx, dy in ((0.25, 0), (0.75, 0), (0, 0.5), (0.5, 0.5), (1.3, 0), (1.3, 0.7), (-0.5, 0), (-0.25, -1.3)):
        specs.append(stack_spec([("plain", 0, 0), ("plain", dx, dy)]))
    specs += [
        stack_spec([("plain", 0, 0), ("plain", 0.5, 0), ("plain", 0.25, 0.75)], note="three plies"),
        stack_spec([("plain", 0, 0), ("plain", 0.5, 0.5), ("plain", -0.25, 0.25), ("plain", 1.3, -0.6)],
                   nest=False, note="four plies, not nested"),
        stack_spec([("twill22", 0, 0), ("twill22", 0.5, 0.5)], note="2/2 twill plies"),
        stack_spec([("satin4", 0, 0), ("satin4", 1.3, -0.5)], note="4-harness satin plies"),
        stack_spec([("twill22", 0, 0), ("plain", 0.5, 0)], note="mixed: a plain ply, 4 x 4 mm, on an 8 x 8 mm twill"),
        stack_spec([("plain", 0, 0), ("satin4", 0.25, 0.5), ("twill22", -0.5, 1.3)],
                   note="mixed: plain, satin and twill plies"),
    ]
    return specs


def _fibre_options(fibres, refine, thickness):
    """The spec entries of a 3D weave's fibre data and refine target (none without fibre data)."""
    if not fibres:
        return {}
    out = dict(fibres=FIBRES)
    if refine:
        out.update(target_thickness=thickness, max_volume_fraction=MAX_VOLUME_FRACTION)
    return out


# ---- building ----------------------------------------------------------------------------------

def rounded_rectangle(w, h):
    """Anticlockwise from (w/2, 0): 18 points of a w x h rectangle with corners of radius 0.4 h."""
    r = 0.4 * h
    pts = [(w / 2, 0.0)]
    for k, (cx, cy) in enumerate([(1, 1), (-1, 1), (-1, -1), (1, -1)]):
        if k == 2:
            pts.append((-w / 2, 0.0))
        for j in range(4):
            a = math.pi / 2 * (k + j / 3)
            pts.append((cx * (w / 2 - r) + r * math.cos(a), cy * (h / 2 - r) + r * math.sin(a)))
    return [(round(x, 9) + 0.0, round(y, 9) + 0.0) for x, y in pts]


def make_section(tc, sec, w, h):
    """The TexGen section and its constructor as text."""
    kind = sec["type"]
    if kind == "CSectionLenticular":
        return tc.CSectionLenticular(w, h), f"CSectionLenticular({fmt(w)}, {fmt(h)})"
    if kind == "CSectionPowerEllipse":
        p = sec["power"]
        return tc.CSectionPowerEllipse(w, h, p), f"CSectionPowerEllipse({fmt(w)}, {fmt(h)}, {fmt(p)})"
    if kind == "CSectionPolygon":
        pts = rounded_rectangle(w, h)
        v = tc.XYVector()
        for x, y in pts:
            v.push_back(tc.XY(x, y))
        return tc.CSectionPolygon(v), f"CSectionPolygon(XYVector of {fmt([list(p) for p in pts])})"
    raise ValueError(kind)


def build_weave2d(tc, s, calls):
    x, y = s["x_yarns"], s["y_yarns"]
    t0 = tc.CTextileWeave2D(s["n"], s["n"], SPACING, s["thickness"], s["refine"])
    calls.append(f"t = CTextileWeave2D({s['n']}, {s['n']}, {fmt(SPACING)}, {fmt(s['thickness'])}, "
                 f"{s['refine']})  # (nX, nY, spacing, thickness, bRefine)")
    t = Recorder(t0, "t", calls)
    for cx, cy in s["swaps"]:
        t.SwapPosition(cx, cy)
    if x["spacing"] != SPACING or y["spacing"] != SPACING:
        t.SetXYarnSpacings(x["spacing"])
        t.SetYYarnSpacings(y["spacing"])
    if (x["width"], x["height"]) == (y["width"], y["height"]):
        t.SetYarnWidths(x["width"])
        t.SetYarnHeights(x["height"])
    else:
        t.SetXYarnWidths(x["width"])
        t.SetXYarnHeights(x["height"])
        t.SetYYarnWidths(y["width"])
        t.SetYYarnHeights(y["height"])
    t.AssignDefaultDomain()
    sec = s["section"]
    if sec["type"] != "CSectionEllipse":
        for axis, data, count, get in (("X", x, t0.GetNumXYarns(), t0.GetXYarns),
                                       ("Y", y, t0.GetNumYYarns(), t0.GetYYarns)):
            section, text = make_section(tc, sec, data["width"], data["height"])
            calls.append(f"for i in range({count}):\n    for yarn in t.Get{axis}Yarns(i):\n"
                         f"        yarn.AssignSection(CYarnSectionConstant({text}))")
            for i in range(count):
                for yarn in get(i):
                    yarn.AssignSection(tc.CYarnSectionConstant(section))
    return t0


def set_3d_sizes(t, s):
    w, f, b = s["warp"], s["weft"], s["binder"]
    t.SetWarpYarnWidths(w["width"])
    t.SetWarpYarnHeights(w["height"])
    t.SetWarpYarnSpacings(w["spacing"])
    t.SetBinderYarnWidths(b["width"])
    t.SetBinderYarnHeights(b["height"])
    t.SetBinderYarnSpacings(b["spacing"])
    t.SetYYarnWidths(f["width"])
    t.SetYYarnHeights(f["height"])
    t.SetYYarnSpacings(f["spacing"])


def set_3d_powers(t, s):
    t.SetWarpYarnPower(s["warp"]["power"])
    t.SetWeftYarnPower(s["weft"]["power"])
    t.SetBinderYarnPower(s["binder"]["power"])


def set_3d_thickness(t0, t, calls):
    """TexGen's 3D weaves leave their FabricThickness uninitialised (the saved attribute is whatever
    was in memory, so the file would change from run to run); set it to the thickness the default
    domain was made for (TexGen's default domain is that thickness plus 5 % above and below). It is
    only a number in the file: the yarns and the domain stay as built."""
    z = [p.z for p in t0.GetDomain().GetMesh().GetNodes()]
    t.SetThickness(num((max(z) - min(z)) / 1.1))
    calls[-1] += "  # = default domain height / 1.1: TexGen leaves it uninitialised"


def start_3d(tc, s, cls, extra, signature, calls):
    """A TexGen 3D weave of class cls (nX, nY, spacings, heights, *extra), recorded, with its warp and
    binder ratios set: (the textile, its recorder)."""
    w, f = s["warp"], s["weft"]
    args = (s["nx"], s["ny"], w["spacing"], f["spacing"], w["height"], f["height"], *extra)
    t0 = getattr(tc, cls)(*args)
    calls.append(f"t = {cls}({', '.join(fmt(a) for a in args)})  # ({signature})")
    t = Recorder(t0, "t", calls)
    t.SetWarpRatio(s["warp_ratio"])
    t.SetBinderRatio(s["binder_ratio"])
    return t0, t


def _fibre_calls(target, kind, f, code=None):
    """The four fibre setters for a yarn kind ("warp", "weft", "binder") as (method, args) pairs:
    per yarn type (code given: CTextile3DWeave's setters) or on one object (a textile or a yarn)."""
    head = () if code is None else (code,)
    return [("SetFibreDiameter", (*head, f["diameter_m"], "m")),
            ("SetFibresPerYarn", (*head, f["per_yarn"][kind])),
            ("SetFibreDensity", (*head, f["density_kg_m3"], "kg/m^3")),
            ("SetYarnLinearDensity", (*head, f["linear_density_kg_m"][kind], "kg/m"))]


def set_3d_fibres(tc, t0, s, calls):
    """Fibre data per yarn type, as TexGen's 3D weave wizard sets it (CTextileOrthogonal passes it
    on to its yarns), in TexGen's default units."""
    f = s["fibres"]
    for code, kind in ((tc.WARP, "warp"), (tc.WEFT, "weft"), (tc.BINDER, "binder")):
        for method, args in _fibre_calls(t0, kind, f, code):
            getattr(t0, method)(*args)
            calls.append(f"t.{method}({kind.upper()}, {', '.join(fmt(a) for a in args[1:])})")


def set_textile_fibres(tc, t0, s, calls):
    """Fibre data of a layer-to-layer or angle-interlock weave, whose classes drop the per-type data
    (they never pass it to their yarns): the warp and weft tow's on the textile (TexGen's default
    for every yarn without its own, CTextile's setters), the binder tow's on each binder yarn (the
    GUI's textile and yarn properties). After the build: the yarns are the built ones, and saved so."""
    f = s["fibres"]
    for method, args in _fibre_calls(t0, "warp", f):
        getattr(tc.CTextile, method)(t0, *args)
        calls.append(f"CTextile.{method}(t, {', '.join(fmt(a) for a in args)})")
    binders = [i for i in range(t0.GetNumXYarns()) if t0.IsBinderYarn(i)]
    for i in binders:
        for yarn in t0.GetXYarns(i):
            for method, args in _fibre_calls(yarn, "binder", f):
                getattr(yarn, method)(*args)
    calls.append(f"for i in {binders}:  # the binder x yarns\n    for yarn in t.GetXYarns(i):\n"
                 + "".join(f"        yarn.{m}({', '.join(fmt(a) for a in args)})\n"
                           for m, args in _fibre_calls(None, "binder", f)).rstrip("\n"))


def set_3d_target(tc, t0, t, s, calls):
    """An orthogonal weave's fibre data, and a refined one's target thickness and maximum volume
    fraction (the wizard's order: before the binder swaps)."""
    if "fibres" not in s or s["kind"] != "orthogonal":
        return
    if s.get("refine"):
        t.SetThickness(s["target_thickness"])
    set_3d_fibres(tc, t0, s, calls)
    if s.get("refine"):
        t.SetMaxVolFraction(s["max_volume_fraction"])


def finish_3d(tc, t0, t, s, calls):
    """Section powers, TexGen's default domain and the fabric thickness: a refined weave's target
    (with the domain's z fitted to what TexGen built, SetDomainZValues, as the wizard does), else
    the one the default domain was made for; then the fibre data of the weaves that do not take it
    per yarn type."""
    set_3d_powers(t, s)
    t.AssignDefaultDomain()
    if s.get("refine"):
        t.SetDomainZValues()
    else:
        set_3d_thickness(t0, t, calls)
    if "fibres" in s and s["kind"] != "orthogonal":
        set_textile_fibres(tc, t0, s, calls)
    return t0


def build_orthogonal(tc, s, calls):
    t0, t = start_3d(tc, s, "CTextileOrthogonal", (s["refine"],),
                     "nX, nY, xSpacing, ySpacing, xHeight, yHeight, bRefine", calls)
    set_3d_sizes(t, s)
    t.SetupLayers(*s["layers"])
    t.SetGapSize(0.0)
    set_3d_target(tc, t0, t, s, calls)
    for cx, cy in s["binder_swaps"]:
        t.SwapBinderPosition(cx, cy)
    return finish_3d(tc, t0, t, s, calls)


def build_layertolayer(tc, s, calls):
    t0, t = start_3d(tc, s, "CTextileLayerToLayer", (s["binder_layers"],),
                     "nX, nY, xSpacing, ySpacing, xHeight, yHeight, nBinderLayers", calls)
    t.SetupLayers(*s["layers"], s["binder_layers"])
    set_3d_sizes(t, s)
    set_3d_target(tc, t0, t, s, calls)
    for yarn, offsets in s["binder_offsets"].items():
        for col, off in enumerate(offsets):
            t.SetBinderPosition(col, yarn, off)
    return finish_3d(tc, t0, t, s, calls)


def build_angleinterlock(tc, s, calls):
    t0, t = start_3d(tc, s, "CTextileAngleInterlock", (), "nX, nY, xSpacing, ySpacing, xHeight, yHeight", calls)
    t.SetupLayers(*s["layers"])
    set_3d_sizes(t, s)
    set_3d_target(tc, t0, t, s, calls)
    for col, yarn in s["binder_tops"]:
        t.SetBinderYarnPositions(col, yarn)
    return finish_3d(tc, t0, t, s, calls)


def default_box(t):
    """The (lo, hi) corners of a TexGen textile's domain, from its mesh's nodes [mm]."""
    pts = [(p.x, p.y, p.z) for p in t.GetDomain().GetMesh().GetNodes()]
    return [num(min(p[k] for p in pts)) for k in range(3)], [num(max(p[k] for p in pts)) for k in range(3)]


def build_layered(tc, s, calls):
    """TexGen's stack: each ply built as build_weave2d builds it, added k ply thicknesses up and moved
    in the plane; the domain the largest ply's default one in plan, the stack's height (5 % of a ply's
    thickness below and above); then NestLayers where asked."""
    stack = tc.CTextileLayered()
    calls.append("s = CTextileLayered()")
    plies, boxes = [], []
    for k, layer in enumerate(s["layers"]):
        ply = build_weave2d(tc, layer["weave"], calls)
        plies.append(ply)  # kept alive while the stack is built
        boxes.append(default_box(ply))
        dx, dy = layer["offset"]
        dz = num(k * layer["weave"]["thickness"])
        stack.AddLayer(ply, tc.XYZ(dx, dy, dz))
        calls.append(f"s.AddLayer(t, XYZ({fmt(dx)}, {fmt(dy)}, {fmt(dz)}))")
    lo, hi = max(boxes, key=lambda b: (b[1][0] - b[0][0]) * (b[1][1] - b[0][1]))
    t_ply = s["layers"][-1]["weave"]["thickness"]
    z_top = sum(layer["weave"]["thickness"] for layer in s["layers"][:-1]) + t_ply
    corners = [[lo[0], lo[1], num(-0.05 * s["layers"][0]["weave"]["thickness"])],
               [hi[0], hi[1], num(z_top + 0.05 * t_ply)]]
    stack.AssignDomain(tc.CDomainPlanes(tc.XYZ(*corners[0]), tc.XYZ(*corners[1])))
    calls.append(f"s.AssignDomain(CDomainPlanes(XYZ({', '.join(map(fmt, corners[0]))}), "
                 f"XYZ({', '.join(map(fmt, corners[1]))})))")
    if s["nest"]:
        stack.NestLayers()
        calls.append("s.NestLayers()")
    return stack


BUILDERS = {"weave2d": build_weave2d, "layered": build_layered, "orthogonal": build_orthogonal,
            "layertolayer": build_layertolayer, "angleinterlock": build_angleinterlock}


def texgen_facts(t, s, path):
    """What TexGen says about the built textile (and the section types in the file it saved)."""
    dom = t.GetDomain()
    pts = [(p.x, p.y, p.z) for p in dom.GetMesh().GetNodes()]
    lo = [num(min(p[k] for p in pts)) for k in range(3)]
    hi = [num(max(p[k] for p in pts)) for k in range(3)]
    ysections = {}
    for i in range(t.GetNumYarns()):
        k = t.GetYarn(i).GetYarnSection().GetType()
        ysections[k] = ysections.get(k, 0) + 1
    sections = {}  # <Section type=...> elements of the saved file (one per yarn, or per node)
    for el in ET.parse(path).getroot().iter("Section"):
        sections[el.get("type")] = sections.get(el.get("type"), 0) + 1
    facts = dict(type=t.GetType(), n_yarns=t.GetNumYarns(), domain_type=dom.GetType(), domain_box=[lo, hi],
                 cell=[num(hi[0] - lo[0]), num(hi[1] - lo[1])],
                 yarn_section_types=dict(sorted(ysections.items())),
                 section_elements_in_file=dict(sorted(sections.items())))
    if s["kind"] == "layered":  # CTextileLayered: its plies (pytexgen returns their yarn lists and offsets
        # as opaque SWIG objects, so those are read from the saved file's <Layer> and <Offset> elements)
        textile = ET.parse(path).getroot().find("Textile")
        facts["layers"] = t.GetNumLayers()
        facts["yarns_per_layer_in_file"] = [len(layer.findall("Yarn")) for layer in textile.findall("Layer")]
        facts["offsets_in_file"] = [[num(float(v)) for v in o.get("value").split(",")]
                                    for o in textile.findall("Offset")]
        # TexGen's own count of each ply's yarn volume per area of fabric [mm^3/mm^2]: each yarn's
        # GetRawYarnVolume (one repeat of its path, TexGen's polygon sections) over GetRawRepeatArea
        facts["ply_volume_per_area_mm"] = [
            num(sum(t.GetYarn(int(y.get("yarnindex"))).GetRawYarnVolume()
                    / t.GetYarn(int(y.get("yarnindex"))).GetRawRepeatArea() for y in layer.findall("Yarn")))
            for layer in textile.findall("Layer")]
        return facts
    facts.update(n_x_yarns=t.GetNumXYarns(), n_y_yarns=t.GetNumYYarns(), refine=bool(t.GetRefine()))
    if s["kind"] == "weave2d":
        facts["fabric_thickness"] = num(t.GetFabricThickness())
    else:
        facts["binder_x_yarns"] = [i for i in range(t.GetNumXYarns()) if t.IsBinderYarn(i)]
    if "fibres" in s:
        facts["fabric_thickness"] = num(t.GetFabricThickness())
        facts["fibre_area_mm2"] = sorted({num(t.GetYarn(i).GetFibreArea("mm^2")) for i in range(t.GetNumYarns())})
    return facts


def params_of(s):
    p = {k: v for k, v in s.items() if k not in ("name", "kind", "family")}
    if "swaps" in p:
        p["swaps"] = [list(c) for c in p["swaps"]]
    for key in ("binder_swaps", "binder_tops"):
        if key in p:
            p[key] = [list(c) for c in p[key]]
    if "binder_offsets" in p:
        p["binder_offsets"] = {str(k): v for k, v in p["binder_offsets"].items()}
    if s["kind"] == "layered":  # a stack: each ply's weave as its own parameters
        p["layers"] = [dict(layer, weave=params_of(layer["weave"])) for layer in p["layers"]]
    return p


def build_one(tc, s, out):
    calls = []
    t = BUILDERS[s["kind"]](tc, s, calls)
    name = s["name"]
    path = os.path.join(out, name + ".tg3")
    tc.AddTextile(name, t, True)
    calls.append(f"AddTextile({name!r}, t, True)")
    calls.append(f"SaveToXML({name + '.tg3'!r}, {name!r}, OUTPUT_STANDARD)")
    if os.path.exists(path):
        os.remove(path)
    tc.SaveToXML(path, name, tc.OUTPUT_STANDARD)
    if not os.path.isfile(path):
        raise RuntimeError(f"TexGen did not save {path}")
    facts = texgen_facts(t, s, path)
    tc.CTexGen.GetInstance().DeleteTextile(name)
    data = open(path, "rb").read()
    return dict(file=name + ".tg3", family=s["family"], cls=facts["type"], parameters=params_of(s),
                texgen_calls=calls, texgen=facts, bytes=len(data), sha256=hashlib.sha256(data).hexdigest())


def compact_json(obj):
    """Indented JSON with lists of numbers (and lists of those) on one line."""
    text = json.dumps(obj, indent=1)
    flat = re.compile(r"\[\s*([-+0-9.eE]+(?:,\s*[-+0-9.eE]+)*)\s*\]")
    text = flat.sub(lambda m: "[" + ", ".join(x.strip() for x in m.group(1).split(",")) + "]", text)
    nested = re.compile(r"\[\s*(\[[^\[\]\n]*\](?:,\s*\[[^\[\]\n]*\])*)\s*\]")
    return nested.sub(lambda m: "[" + re.sub(r"\],\s*\[", "], [", m.group(1)) + "]", text)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=OUT,
                    help="folder for the .tg3 files and index.json (default %(default)s)")
    ap.add_argument("--only", nargs="+", metavar="NAME", help="build only these models (no index.json)")
    ap.add_argument("--list", action="store_true", help="print the model names and exit")
    args = ap.parse_args(argv)
    specs = family()
    names = [s["name"] for s in specs]
    assert len(set(names)) == len(names), "duplicate model names"
    if args.list:
        print("\n".join(names))
        return 0
    if args.only:
        unknown = sorted(set(args.only) - set(names))
        if unknown:
            ap.error(f"unknown model(s): {', '.join(unknown)}")
        specs = [s for s in specs if s["name"] in args.only]

    import pytexgen.Core as tc

    tc.CTexGen.GetInstance().SetMessages(False)
    os.makedirs(args.out, exist_ok=True)
    entries = []
    for s in specs:
        e = build_one(tc, s, args.out)
        entries.append(e)
        print(f"{e['file']}: {e['cls']}, {e['texgen']['n_yarns']} yarns, {e['bytes']} bytes", file=sys.stderr)
    if not args.only:
        index = dict(
            texgen_version=tc.CTexGen.GetInstance().GetVersion(),
            made_by="PY=$(bench/texgen_env.sh) && $PY bench/make_fabrics.py",
            conventions=("x yarns run along x (TexGen's X yarns, spaced in y); "
                         "y yarns along y (spaced in x). "
                         "width_over_spacing, height_over_width per yarn family; lengths in mm. "
                         "texgen_calls: the calls in order, as Python (from pytexgen.Core import *)."),
            models=entries)
        with open(os.path.join(args.out, "index.json"), "w") as f:
            f.write(compact_json(index) + "\n")
        made = {e["file"] for e in entries}
        stale = sorted(n for n in os.listdir(args.out) if n.endswith(".tg3") and n not in made)
        if stale:
            print(f"note: {args.out} also holds {', '.join(stale)}, not made by this script", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
