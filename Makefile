# Every target runs inside the FEniCSx 0.9 environment through bin/fenicsx-env (which builds it
# once when the host has no DOLFINx 0.9). `make help` lists the targets.
ENV      := bin/fenicsx-env
PYTEST   := python3 -m pytest -p no:cacheprovider
MPIRUN   := mpirun -n 2
OUT      ?= output

.PHONY: help env demo test test-serial test-mpi clean

help:
	@echo "make demo         run the default job; outputs in $(OUT)/plate_c0ip/"
	@echo "make test         serial test pass, then the mpi-marked tests under $(MPIRUN)"
	@echo "make env          build (or check) the FEniCSx 0.9 environment only"
	@echo "make clean        remove $(OUT)/"

env:
	$(ENV) textile-fenicsx versions

demo:
	$(ENV) env TEXTILE_FENICSX_OUT=$(OUT)/plate_c0ip python3 demos/plate_c0ip.py

test: test-serial test-mpi

test-serial:
	$(ENV) $(PYTEST) tests

test-mpi:
	$(ENV) $(MPIRUN) $(PYTEST) --color=no -m mpi tests

clean:
	rm -rf $(OUT)
