# Every target runs inside the FEniCSx 0.9 environment through bin/fenicsx-env (which builds it
# once when the host has no DOLFINx 0.9). `make help` lists the targets.
ENV      := bin/fenicsx-env
PYTEST   := python3 -m pytest -p no:cacheprovider
# the serial pass on two pytest-xdist workers (one per core; 0: in one process)
WORKERS  ?= 2
MPIRUN   := mpirun -n 2
# the fast tier (make test) leaves out what the slow tier (make test-all) adds: tests marked slow or
# convergence (whole 3D weaves, demos, large tet fixtures), chosen by the durations both print
FAST     := not sweep and not slow and not convergence
SLOW     := (slow or convergence) and not sweep
DURATIONS := --durations=25
OUT      ?= output

.PHONY: help env demo demos test test-serial test-mpi test-all test-slow test-slow-serial test-slow-mpi lint docker-test bench bench-outer bench-volume bench-flow sweep sweep-flow sweep-volume sweep-compaction clean

help:
	@echo "make demo         the default job: the 4-harness satin, corrected; outputs in $(OUT)/satin_4hs/"
	@echo "make demos        every demo, outputs in $(OUT)/<demo>/"
	@echo "make test         the fast tier (under 12 min on 2 cores): serial pass (on WORKERS=2 pytest-xdist"
	@echo "                  workers), then the mpi-marked tests under $(MPIRUN); slow and convergence tests left out"
	@echo "make test-all     make test, then the slow tier: the slow and convergence tests, serial and under"
	@echo "                  $(MPIRUN) (about 20 min more)"
	@echo "make lint         ruff (rules in pyproject.toml) and mypy on the package; pinned tools from PyPI,"
	@echo "                  installed once by bin/lint on the host (under a minute), then a few seconds"
	@echo "make bench        the pipeline stage by stage on the satin (seeds 1-0.125), the orthogonal weave and"
	@echo "                  satin coupons (4x4, 8x8), serial and 2 ranks; table + $(OUT)/bench.json (~20 min;"
	@echo "                  make bench QUICK=1: the unit cells only, ~3 min); then make bench-volume's table"
	@echo "                  (QUICK=1: voxel, serial, ~4 min more)"
	@echo "make bench-outer  CG with yarn-block and multigrid preconditioners on the contact steps' matrices (satin4,"
	@echo "                  seed 0.25): why the steps use a direct solve (~1 min); table on stdout"
	@echo "make bench-volume volume-mesh + homogenise + permeability of the corrected satin4 (voxel and tet, 1 and 2 ranks): seconds,"
	@echo "                  dofs, peak memory; table + $(OUT)/volume_bench.json"
	@echo "make bench-flow   the flow solver against the yarns' drag: FGMRES iterations and K against MUMPS' on the"
	@echo "                  corrected satin4's voxels (0.6, 0.3 mm), yarns from 1e-8 m^2 to solid (~10 min)"
	@echo "make sweep        the default command on every fabric of reference/fabrics (~1 h); table + $(OUT)/sweep.json"
	@echo "make sweep-flow   every 2D fabric of the sweep solved, meshed as voxels (0.3 mm, 4 layers) and its"
	@echo "                  permeability computed; table + $(OUT)/flow_sweep.json"
	@echo "make sweep-compaction  every 2D fabric of the sweep solved, then pressed to Vf 0.5 (K 50 MPa)"
	@echo "make sweep-volume the volume stage on the same family: voxel of each input, solve --volume-mesh tet,"
	@echo "                  voxel of the corrected model, homogenise (~3 h); table + $(OUT)/volume_sweep.json"
	@echo "make docker-test  build the Dockerfile in a Docker engine of its own, run the demos (satin; orthogonal on"
	@echo "                  2 ranks) in the image as a non-root user and compare them with bin/fenicsx-env's, run"
	@echo "                  the tests in the image; as root; about 10 min (13 cold); $(OUT)/docker-test/"
	@echo "make env          build (or check) the FEniCSx 0.9 environment only"
	@echo "make clean        remove $(OUT)/"

env:
	$(ENV) textile-fenicsx versions

demo:
	$(ENV) env TEXTILE_FENICSX_OUT=$(OUT)/satin_4hs python3 demos/satin_4hs.py

demos:
	for d in satin_4hs orthogonal_3d mesh_convergence parameter_study plate_c0ip coupon_edges homogenise_satin \
	  compaction_satin nested_laminate; do \
	  $(ENV) env TEXTILE_FENICSX_OUT=$(OUT)/$$d python3 demos/$$d.py || exit 1; done

test: test-serial test-mpi

test-serial:
	$(ENV) $(PYTEST) -n $(WORKERS) -m "$(FAST)" $(DURATIONS) tests

test-mpi:
	$(ENV) $(MPIRUN) $(PYTEST) --color=no -m "mpi and ($(FAST))" $(DURATIONS) tests

test-all: test test-slow

test-slow: test-slow-serial test-slow-mpi

test-slow-serial:
	$(ENV) $(PYTEST) -n $(WORKERS) -m "$(SLOW)" $(DURATIONS) tests

test-slow-mpi:
	$(ENV) $(MPIRUN) $(PYTEST) --color=no -m "mpi and ($(SLOW))" $(DURATIONS) tests

lint:
	bin/lint ruff
	bin/lint mypy

docker-test:
	bin/docker-test $(OUT)/docker-test

bench:
	@texgen=$$(bench/texgen_env.sh --fenicsx-env 2>/dev/null || true); \
	$(ENV) env TEXTILE_FENICSX_TEXGEN_PYTHON=$$texgen python3 bench/bench.py --out $(OUT)/bench.json $(if $(QUICK),--quick)
	$(ENV) python3 bench/volume_bench.py --out $(OUT)/volume_bench.json $(if $(QUICK),--kinds voxel --ranks 1)
	$(ENV) python3 bench/compaction_bench.py --out $(OUT)/compaction_bench.json $(if $(QUICK),--seeds 0.5 --repeat 1)

bench-outer:
	$(ENV) python3 bench/outer_solve.py

bench-volume:
	$(ENV) python3 bench/volume_bench.py --out $(OUT)/volume_bench.json

bench-flow:
	$(ENV) python3 bench/flow_contrast.py --out $(OUT)/flow_contrast.json

sweep-flow:
	$(ENV) python3 bench/flow_sweep.py --out $(OUT)/flow_sweep.json

sweep:
	$(ENV) python3 bench/sweep.py --out $(OUT)/sweep.json

sweep-compaction:
	$(ENV) python3 bench/sweep.py --compaction 50 --vf 0.5 --out $(OUT)/compaction_sweep.json

sweep-volume:
	$(ENV) python3 bench/volume_sweep.py --out $(OUT)/volume_sweep.json

clean:
	rm -rf $(OUT)
