# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: light
# ---

# # An anisotropic plate with the C0 interior-penalty method
#
# Every yarn of a textile is modelled as a Kirchhoff plate whose bending stiffness depends on the
# fibre direction $d$: in the frame $(d, n)$, with $H = \nabla\nabla z$,
#
# $$ \psi = \tfrac12\left(D_{b1} k_{11}^2 + D_{b2} k_{22}^2 + 4 D_{b12} k_{12}^2\right),\qquad
#    k_{11} = d\cdot H d,\; k_{22} = n\cdot H n,\; k_{12} = d\cdot H n .$$
#
# Continuous P2 elements have no continuous slope, so the C0 interior-penalty (C0IP) form adds, on
# every interior facet, the average normal moment times the jump of the normal slope (both ways
# round) and a penalty $\alpha D/h$ on that jump. This demo verifies that form on a clamped unit
# square with fibres at 30 degrees: we choose the deflection
# $z_e = \sin(\pi x)\sin(2\pi y) + x^3 y/4$, compute the load $f = \nabla\cdot\nabla\cdot M(z_e)$
# that produces it, solve on refined meshes and watch the $L^2$ error fall as $h^2$
# (the known rate of P2 C0IP). The textile solver uses the same form.

# +
import os
import time
from pathlib import Path

from mpi4py import MPI

import dolfinx.io
from textile_fenicsx.plate.verification import AnisotropicPlate, convergence_rates, solve_manufactured_plate
from textile_fenicsx.plot.plotting import plot_height_field

comm = MPI.COMM_WORLD
out = Path(os.environ.get("TEXTILE_FENICSX_OUT", "output/plate_c0ip"))
if comm.rank == 0:
    out.mkdir(parents=True, exist_ok=True)
    print(f"plate_c0ip: writing to {out}/ on {comm.size} rank(s)", flush=True)
# -

# Stiffnesses along, across and in twist of the fibre, and the fibre angle:

case = AnisotropicPlate(Db1=1.0, Db2=0.2, Db12=0.3, angle_deg=30.0, alpha=8.0)

# Solve on a sequence of meshes:

# +
hs, errors = [], []
for n in (8, 16, 32, 64):
    start = time.perf_counter()
    sol = solve_manufactured_plate(case, n)
    hs.append(sol.h)
    errors.append(sol.error_L2)
    if comm.rank == 0:
        print(f"  n = {n:3d}: {sol.dofs:6d} dofs, L2 error {sol.error_L2:.3e}, "
              f"{time.perf_counter() - start:.2f} s", flush=True)
rates = convergence_rates(hs, errors)
if comm.rank == 0:
    print("  observed L2 rates:", " ".join(f"{r:.2f}" for r in rates), "(expected 2)")
# -

# Write the finest solution for ParaView (XDMF holds fields of the mesh's degree, so we store the
# P1 interpolant) and a picture:

# +
msh = sol.w.function_space.mesh
w1 = dolfinx.fem.Function(dolfinx.fem.functionspace(msh, ("Lagrange", 1)), name="w")
w1.interpolate(sol.w)
with dolfinx.io.XDMFFile(comm, out / "plate.xdmf", "w") as f:
    f.write_mesh(msh)
    f.write_function(w1)
plot_height_field(sol.w, out / "plate.png", f"C0IP plate, fibres at {case.angle_deg:g} deg, "
                  f"L2 rate {rates[-1]:.2f}", warp=0.3)
if comm.rank == 0:
    print(f"plate_c0ip: wrote {out / 'plate.xdmf'} and {out / 'plate.png'}", flush=True)
# -
