#!/usr/bin/env python3
"""Measure or solve a textile model with TexGen's own code (PyPI pytexgen 1.2.1).

An independent check of textile_fenicsx: this script never imports it, and runs under the Python
that bench/texgen_env.sh prints, not in the FEniCSx environment's own interpreter:

    PY=$(bench/texgen_env.sh)                                  # host
    PY=$(bench/texgen_env.sh --fenicsx-env)                    # inside bin/fenicsx-env (tests, bench)
    $PY bench/texgen.py measure FILE.tg3 [--grid N] [--textile NAME]
    $PY bench/texgen.py solve NAME_OR_FILE.tg3 SEED OUTDIR [--timeout SECONDS]

Each prints one JSON object on stdout; TexGen's own messages and errors go to stderr (exit 1 on error).

measure
    TexGen reads the file (CTexGen.ReadFromXML) and builds every yarn its own way (interpolation,
    sections, slave nodes). Inside-ness is found by casting vertical rays through TexGen's yarn surfaces:
    CYarn.AddSurfaceToMesh(mesh, False) gives the triangulated surface of one period of a yarn, an open
    tube; its copies shifted by CDomain.GetTranslations(yarn) are every copy that reaches the domain, and
    consecutive copies meet without a gap. One vertical line per cell of an N x N grid over the domain's
    x-y box (through the cell centre, moved by 1e-7 cell so that it cannot run exactly through a mesh
    edge) is cut with all triangles of a yarn; along the line the crossings alternate in and out, so
    consecutive pairs are the z-intervals inside the yarn. These are exact for TexGen's facetted surface:
    the only discretisation is the plan grid (each line stands for its cell), about one cell (box / N) of
    error at yarn edges. A line that crosses a yarn's surface an odd number of times (touching it) is
    redone with TexGen's point classifier CTextile.GetPointInformation(points, info, yarn, tol) at 400
    points over the yarn's z range. From the intervals, with A the cell area and in the domain box:
      interpenetration.volume     A * sum over lines of the length inside two or more yarns (z clipped
                                  to the domain; volume_all_z: not clipped)
      interpenetration.max_depth  max over lines and yarn pairs of the length inside both (all z)
      yarn_volume.per_yarn/total  A * sum of each yarn's lengths, z clipped to the domain
      thickness                   max z - min z of all yarn surface points (whole yarns)
    "Inside two yarns" means inside two different yarns (a yarn's periodic copies count as that yarn).

solve
    TexGen's geometry solver (CGeometrySolver, the implementation of the paper; parameters set to its
    defaults: tensile stress 1, bending moduli 1 and 1, contact stiffness 1e3, disabled stiffness 1e-4)
    at the given seed on the model's only textile: CreateSystem, SolveSystem, GetDeformedCopyOfTextile,
    timed together ("seconds": wall clock, "cpu_seconds": CPU time of the process); the deformed textile
    is saved to OUTDIR/texgen_corrected.tg3. A NAME without ".tg3" means reference/models/NAME.tg3 of
    this repository. With --timeout the solve runs in a child process that is killed after that many
    seconds, and the JSON is {"timeout": true, ...} (exit status 0 as well).
"""

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MODELS = os.path.join(REPO, "reference", "models")
RAY_SHIFT = 1.234e-7  # of a cell: rays never hit the regular points of a TexGen mesh exactly
CLASSIFIER_SAMPLES = 400  # points along z for a ray redone with TexGen's classifier
SOLVER_DEFAULTS = dict(TensileStress=1.0, LongitudinalBendingModulus=1.0, TransverseBendingModulus=1.0,
                       ContactStiffness=1e3, DisabledStiffness=1e-4)


class Failure(Exception):
    pass


def texgen(messages=False):
    import pytexgen.Core as tc

    tc.CTexGen.GetInstance().SetMessages(bool(messages))
    return tc


def read_model(tc, path):
    """ReadFromXML(path); the names of the textiles the file added."""
    if not os.path.isfile(path):
        raise Failure(f"no such file: {path}")
    tg = tc.CTexGen.GetInstance()
    before = set(tg.GetTextiles().keys())
    if not tg.ReadFromXML(path):
        raise Failure(f"TexGen could not read {path}")
    names = [n for n in tg.GetTextiles().keys() if n not in before]
    if not names:
        raise Failure(f"{path} holds no textile")
    return names


# ---- measure -----------------------------------------------------------------------------------

def surface(tc, yarn):
    """TexGen's surface of one period of the yarn: points (n, 3) and triangles (m, 3)."""
    mesh = tc.CMesh()
    if not yarn.AddSurfaceToMesh(mesh, False):
        raise Failure("TexGen could not build a yarn surface")
    mesh.ConvertToTriangleMesh()
    pts = np.array([(p.x, p.y, p.z) for p in mesh.GetNodes()], float).reshape(-1, 3)
    tri = np.array(mesh.GetIndices(tc.CMesh.TRI), np.int64).reshape(-1, 3)
    return pts, tri


def line_at(i, lo, h):
    """Plan coordinate of grid line i along one axis (lo, h: that axis's start and cell size)."""
    return lo + (i + 0.5 + RAY_SHIFT) * h


def ray_hits(a, b, c, lo, h, n):
    """Crossings of the triangles (a, b, c: (m, 3) each) with the vertical lines of the n x n grid:
    (line index ix * n + iy, z) for every crossing."""
    rng = []
    for k in (0, 1):
        vmin = np.minimum(np.minimum(a[:, k], b[:, k]), c[:, k])
        vmax = np.maximum(np.maximum(a[:, k], b[:, k]), c[:, k])
        i0 = np.clip(np.ceil((vmin - lo[k]) / h[k] - 0.5 - RAY_SHIFT), 0, n).astype(np.int64)
        i1 = np.clip(np.floor((vmax - lo[k]) / h[k] - 0.5 - RAY_SHIFT), -1, n - 1).astype(np.int64)
        rng.append((i0, np.maximum(i1 - i0 + 1, 0)))
    (ix0, nx), (iy0, ny) = rng
    count = nx * ny
    t = np.repeat(np.arange(len(a)), count)  # one entry per (triangle, line) candidate
    k = np.arange(t.size) - np.repeat(np.cumsum(count) - count, count)
    ix = ix0[t] + k % np.maximum(nx[t], 1)
    iy = iy0[t] + k // np.maximum(nx[t], 1)
    px, py = line_at(ix, lo[0], h[0]), line_at(iy, lo[1], h[1])
    A, B, C = a[t], b[t], c[t]

    def orient(p, q):  # twice the signed area of (p, q, ray point) in plan
        return (q[:, 0] - p[:, 0]) * (py - p[:, 1]) - (q[:, 1] - p[:, 1]) * (px - p[:, 0])

    wa, wb, wc = orient(B, C), orient(C, A), orient(A, B)
    area = wa + wb + wc
    s = np.sign(area)
    hit = (area != 0) & (wa * s >= 0) & (wb * s >= 0) & (wc * s >= 0)
    z = (wa * A[:, 2] + wb * B[:, 2] + wc * C[:, 2])[hit] / area[hit]
    return (ix * n + iy)[hit], z


def classify_lines(tc, tex, iyarn, lines, zlo, zhi, lo, h, n, tol=1e-9):
    """TexGen's point classifier on CLASSIFIER_SAMPLES points of each given line between zlo and zhi;
    returns the inside intervals as (line, za, zb)."""
    dz = (zhi - zlo) / CLASSIFIER_SAMPLES
    zs = zlo + (np.arange(CLASSIFIER_SAMPLES) + 0.5) * dz
    pts = tc.XYZVector()
    for line in lines:
        x, y = line_at(line // n, lo[0], h[0]), line_at(line % n, lo[1], h[1])
        for z in zs:
            pts.push_back(tc.XYZ(float(x), float(y), float(z)))
    info = tc.PointInfoVector()
    tex.GetPointInformation(pts, info, iyarn, tol)
    inside = np.array([p.iYarnIndex == iyarn for p in info], bool).reshape(len(lines), -1)
    out = []
    for line, row in zip(lines, inside):
        edge = np.diff(np.r_[0, row.astype(np.int8), 0])
        for s, e in zip(np.flatnonzero(edge == 1), np.flatnonzero(edge == -1)):
            out.append((line, zlo + s * dz, zlo + e * dz))
    return out


def yarn_intervals(tc, tex, dom, iyarn, lo, h, n):
    """z-intervals inside yarn iyarn along the grid lines: (line, za, zb) arrays, its surface's z range,
    and how many lines were redone with the classifier."""
    yarn = tex.GetYarn(iyarn)
    pts, tri = surface(tc, yarn)
    lines, zs = [np.zeros(0, np.int64)], [np.zeros(0)]
    zmin, zmax = pts[:, 2].min(), pts[:, 2].max()
    for t in dom.GetTranslations(yarn):  # none if the yarn misses the domain
        p = pts + (t.x, t.y, t.z)
        zmin, zmax = min(zmin, p[:, 2].min()), max(zmax, p[:, 2].max())
        line, z = ray_hits(p[tri[:, 0]], p[tri[:, 1]], p[tri[:, 2]], lo, h, n)
        lines.append(line)
        zs.append(z)
    line, z = np.concatenate(lines), np.concatenate(zs)
    order = np.lexsort((z, line))
    line, z = line[order], z[order]
    odd = np.flatnonzero(np.bincount(line, minlength=n * n) % 2)
    keep = ~np.isin(line, odd)
    line, z = line[keep], z[keep]
    rank = np.arange(line.size) - np.searchsorted(line, line)  # position within its line
    cols, za, zb = line[rank % 2 == 0], z[rank % 2 == 0], z[rank % 2 == 1]
    if odd.size:
        extra = classify_lines(tc, tex, iyarn, odd, zmin, zmax, lo, h, n)
        if extra:
            e = np.array(extra, float)
            cols = np.r_[cols, e[:, 0].astype(np.int64)]
            za, zb = np.r_[za, e[:, 1]], np.r_[zb, e[:, 2]]
    return cols, za, zb, (zmin, zmax), int(odd.size)


def covered(cols, za, zb, nlines, k):
    """Per line: the length covered by at least k of the intervals (line, za, zb)."""
    if cols.size == 0:
        return np.zeros(nlines)
    c = np.r_[cols, cols]
    z = np.r_[za, zb]
    d = np.r_[np.ones(cols.size, np.int64), -np.ones(cols.size, np.int64)]
    order = np.lexsort((d, z, c))  # per line along z; at equal z an end before a start
    c, z, d = c[order], z[order], d[order]
    level = np.cumsum(d)  # back to 0 at the end of every line
    on = (c[1:] == c[:-1]) & (level[:-1] >= k)
    return np.bincount(c[:-1][on], weights=np.diff(z)[on], minlength=nlines)


def measure_textile(tc, tex, name, n):
    start = time.perf_counter()
    dom = tex.GetDomain()
    if dom is None:
        raise Failure(f"textile {name} has no domain")
    corners = np.array([(p.x, p.y, p.z) for p in dom.GetMesh().GetNodes()], float)
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    h = (hi[:2] - lo[:2]) / n
    cell = float(h[0] * h[1])
    nlines = n * n
    nyarn = tex.GetNumYarns()

    per_yarn, zrange, n_odd = [], [np.inf, -np.inf], 0
    all_c, all_a, all_b = [], [], []
    for i in range(nyarn):
        cols, za, zb, (z0, z1), odd = yarn_intervals(tc, tex, dom, i, lo, h, n)
        zrange = [min(zrange[0], z0), max(zrange[1], z1)]
        n_odd += odd
        inside = np.clip(zb, lo[2], hi[2]) - np.clip(za, lo[2], hi[2])
        per_yarn.append(float(inside.sum() * cell))
        all_c.append(cols), all_a.append(za), all_b.append(zb)
    yarn_of = np.repeat(np.arange(nyarn), [c.size for c in all_c])
    cols, za, zb = np.concatenate(all_c), np.concatenate(all_a), np.concatenate(all_b)

    over_all_z = covered(cols, za, zb, nlines, 2)
    ca, cb = np.clip(za, lo[2], hi[2]), np.clip(zb, lo[2], hi[2])
    in_box = cb > ca
    volume = float(covered(cols[in_box], ca[in_box], cb[in_box], nlines, 2).sum() * cell)

    # deepest vertical overlap of two yarns: only lines where some two overlap, pair by pair
    hot = over_all_z > 0
    sel = hot[cols]
    cols_h, za_h, zb_h, yarn_h = cols[sel], za[sel], zb[sel], yarn_of[sel]
    depth, pair, where = 0.0, None, None
    present = [i for i in range(nyarn) if np.any(yarn_h == i)]
    for ii, i in enumerate(present):
        for j in present[ii + 1:]:
            m = (yarn_h == i) | (yarn_h == j)
            both = covered(cols_h[m], za_h[m], zb_h[m], nlines, 2)
            best = int(np.argmax(both))
            if both[best] > depth:
                depth, pair = float(both[best]), [i, j]
                where = [float(lo[0] + (best // n + 0.5) * h[0]), float(lo[1] + (best % n + 0.5) * h[1])]

    box_volume = float(np.prod(hi - lo))
    return dict(
        textile=name, type=tex.GetType(), n_yarns=nyarn,
        layers=tex.GetLayeredTextile().GetNumLayers() if tex.GetType() == "CTextileLayered" else None,
        domain_box=[lo.tolist(), hi.tolist()], domain_volume=box_volume,
        grid=dict(n=[n, n], h=h.tolist(), method="vertical rays through TexGen's yarn surfaces",
                  lines_redone_with_classifier=n_odd),
        interpenetration=dict(volume=volume, fraction_of_domain=volume / box_volume,
                              volume_all_z=float(over_all_z.sum() * cell),
                              max_depth=depth, max_depth_yarns=pair, max_depth_xy=where),
        yarn_volume=dict(per_yarn=per_yarn, total=float(sum(per_yarn))),
        thickness=float(zrange[1] - zrange[0]), z_range=[float(zrange[0]), float(zrange[1])],
        seconds=time.perf_counter() - start,
    )


def cmd_measure(args):
    if args.grid < 1:
        raise Failure("--grid must be at least 1")
    tc = texgen()
    path = os.path.abspath(args.file)
    names = read_model(tc, path)
    if args.textile:
        if args.textile not in names:
            raise Failure(f"{path} has no textile {args.textile!r} (it has {', '.join(names)})")
        names = [args.textile]
    results = [measure_textile(tc, tc.CTexGen.GetInstance().GetTextile(nm), nm, args.grid) for nm in names]
    if len(results) == 1:
        return dict(file=path, **results[0])
    return dict(file=path, textiles=results)


# ---- solve -------------------------------------------------------------------------------------

def model_path(arg):
    if arg.endswith(".tg3") or os.sep in arg:
        return os.path.abspath(arg)
    return os.path.join(MODELS, arg + ".tg3")


def cmd_solve(args):
    model = model_path(args.model)
    if not os.path.isfile(model):
        raise Failure(f"no such model: {model}")
    if args.seed <= 0:
        raise Failure("SEED must be positive")
    if args.timeout is not None:
        return solve_in_child(args, model)
    tc = texgen(messages=args.texgen_messages)
    names = read_model(tc, model)
    if len(names) != 1:
        raise Failure(f"{model} holds {len(names)} textiles; solve needs exactly one")
    solver = tc.CGeometrySolver()
    solver.SetSeed(args.seed)
    for key, value in SOLVER_DEFAULTS.items():
        getattr(solver, "Set" + key)(value)
    t0, cpu0 = time.perf_counter(), time.process_time()
    if not solver.CreateSystem(names[0]):
        raise Failure(f"TexGen's CGeometrySolver.CreateSystem failed on {model}")
    t1 = time.perf_counter()
    iterations = solver.SolveSystem()
    t2 = time.perf_counter()
    deformed = solver.GetDeformedCopyOfTextile()
    seconds, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    tg = tc.CTexGen.GetInstance()
    name = deformed.GetName()
    if name not in tg.GetTextiles().keys():
        name = names[0] + "_texgen_corrected"
        tg.AddTextile(name, deformed)
    os.makedirs(args.outdir, exist_ok=True)
    out = os.path.abspath(os.path.join(args.outdir, "texgen_corrected.tg3"))
    if os.path.exists(out):
        os.remove(out)
    tc.SaveToXML(out, name, tc.OUTPUT_STANDARD)  # returns nothing
    if not os.path.isfile(out) or os.path.getsize(out) == 0:
        raise Failure(f"TexGen could not write {out}")
    return dict(seconds=seconds, seed=args.seed, file=out, model=model, textile=names[0], cpu_seconds=cpu,
                iterations=int(iterations), seconds_create=t1 - t0, seconds_solve=t2 - t1,
                seconds_deform=seconds - (t2 - t0),
                parameters={k: getattr(solver, "Get" + k)() for k in SOLVER_DEFAULTS})


def solve_in_child(args, model):
    cmd = [sys.executable, os.path.abspath(__file__), "solve", model, repr(args.seed), args.outdir]
    if args.texgen_messages:
        cmd.append("--texgen-messages")
    start = time.perf_counter()
    try:
        run = subprocess.run(cmd, stdout=subprocess.PIPE, text=True, timeout=args.timeout)
    except subprocess.TimeoutExpired:  # subprocess.run has killed and reaped the child
        return dict(timeout=True, seconds=time.perf_counter() - start, limit=args.timeout, seed=args.seed,
                    model=model)
    if run.returncode != 0:
        raise Failure(f"the solve failed (exit status {run.returncode}; its messages are above)")
    return json.loads(run.stdout)


# ---- main --------------------------------------------------------------------------------------

def main(argv=None):
    ap = argparse.ArgumentParser(prog="texgen.py", description=__doc__.split("\n")[0],
                                 epilog="Method and fields: see the docstring of bench/texgen.py.")
    sub = ap.add_subparsers(dest="command", required=True)
    m = sub.add_parser("measure", help="interpenetration, yarn volumes and thickness, measured by TexGen")
    m.add_argument("file", help="a .tg3 file")
    m.add_argument("--grid", type=int, default=200, help="N x N vertical lines over the domain (default 200)")
    m.add_argument("--textile", help="measure only this textile of the file")
    s = sub.add_parser("solve", help="TexGen's geometry solver, timed")
    s.add_argument("model", help="a .tg3 file, or NAME for reference/models/NAME.tg3")
    s.add_argument("seed", type=float)
    s.add_argument("outdir")
    s.add_argument("--timeout", type=float, help="kill the solve after this many seconds")
    s.add_argument("--texgen-messages", action="store_true", help="show TexGen's log (on stderr)")
    args = ap.parse_args(argv)

    # TexGen writes to the process's stdout; keep that for the JSON alone.
    out = os.fdopen(os.dup(1), "w")
    sys.stdout.flush()
    os.dup2(2, 1)
    try:
        result = cmd_measure(args) if args.command == "measure" else cmd_solve(args)
    except Failure as e:
        print(f"texgen.py: error: {e}", file=sys.stderr)
        return 1
    out.write(json.dumps(result, indent=1) + "\n")
    out.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
