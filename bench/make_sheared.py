#!/usr/bin/env python3
"""Build TexGen's sheared 2D weaves (CShearedTextileWeave2D, PyPI pytexgen 1.2.1) for the tests.

Runs under the Python that bench/texgen_env.sh prints (never imports textile_fenicsx):

    PY=$(bench/texgen_env.sh)      # or, on a host without it: bin/fenicsx-env $(bench/texgen_env.sh --fenicsx-env)
    $PY bench/make_sheared.py [--out DIR]

DIR (default tests/data/sheared) gets, for plain, 2/2 twill and the 4-harness crowfoot satin at
0, 15, 30 and 40 degrees, NAME_gDEG.tg3 with TexGen's sheared domain (AssignDefaultDomain(True):
its x sides lean along the wefts), plus plain_g30_box.tg3 with the default domain
(AssignDefaultDomain(): a box) and plain_weave2d.tg3, CTextileWeave2D's plain weave of the same
sizes. Spacing 2.0 mm, width 1.4 mm (the yarns jam at acos(0.7) = 45.6 degrees), height 0.28 mm,
fabric thickness 0.56 mm, ellipses, refine off, in-plane tangents (TexGen's defaults).
Everything is fixed in this script: re-running gives the same files.
"""

import argparse
import math
from pathlib import Path

from pytexgen.Core import OUTPUT_STANDARD, AddTextile, CShearedTextileWeave2D, CTextileWeave2D, SaveToXML

SPACING, WIDTH, HEIGHT, THICKNESS = 2.0, 1.4, 0.28, 0.56
PATTERNS = {  # (warp i, weft j) positions swapped from TexGen's default (y yarn over), as make_fabrics.py
    "plain": (2, [(0, 0), (1, 1)]),
    "twill22": (4, [(j, i) for i in range(4) for j in range(4) if (j - i) % 4 < 2]),
    "satin4": (4, [(j, i) for i in range(4) for j in range(4) if (i, j) not in ((0, 0), (1, 1), (2, 3), (3, 2))]),
}


def weave(kind: str, n: int, swaps, shear: float | None, sheared_domain: bool):
    """TexGen's weave: the sheared class at `shear` degrees, or CTextileWeave2D (shear None)."""
    if shear is None:
        w = CTextileWeave2D(n, n, SPACING, THICKNESS, False, True)
    else:
        w = CShearedTextileWeave2D(n, n, SPACING, THICKNESS, math.radians(shear), False, True)
    w.SetYarnWidths(WIDTH)
    w.SetYarnHeights(HEIGHT)
    for x, y in swaps:
        w.SwapPosition(x, y)
    if shear is None:
        w.AssignDefaultDomain()
    else:
        w.AssignDefaultDomain(sheared_domain)
    return w


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(Path(__file__).resolve().parent.parent / "tests/data/sheared"))
    out = Path(parser.parse_args().out)
    out.mkdir(parents=True, exist_ok=True)
    jobs = [(f"{k}_g{g}", k, g, True) for k in PATTERNS for g in (0, 15, 30, 40)]
    jobs += [("plain_g30_box", "plain", 30, False), ("plain_weave2d", "plain", None, False)]
    for name, kind, shear, sheared_domain in jobs:
        n, swaps = PATTERNS[kind]
        AddTextile(name, weave(kind, n, swaps, shear, sheared_domain), True)
        SaveToXML(str(out / f"{name}.tg3"), name, OUTPUT_STANDARD)


if __name__ == "__main__":
    main()
