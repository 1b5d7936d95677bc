# Two commands do everything on a fresh Debian machine:
#   make demo   -- set up (apt + .venv + parallel h5py, once), run a small MPI campaign (mpirun -n 2), analyze it
#   make test   -- set up, then the test suite (what CI runs)
# Further: make bench (BENCHMARKS.md, ~25 min), make validate (VALIDATION.md, ~9 min),
#          make faults (the kills at exact moments left out of make test, then FAULTS.md: 40 campaigns
#          SIGKILLed at random moments, resumed, compared; ~26 min on 2 cores, 2026-12-07), make reproduce (REPRODUCTION.md),
#          make contrast (its viscosity-contrast sections, ~30 min).

PY      := .venv/bin/python
HPCVES  := .venv/bin/hpcves
DEMO    := out/demo
# mpirun for one machine: as root Open MPI wants the two ALLOW variables; shared memory
# transport only; oversubscription allowed (override MPIRUN on a cluster).
MPIRUN  ?= env OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 \
           OMPI_MCA_rmaps_base_oversubscribe=1 OMPI_MCA_pml=ob1 OMPI_MCA_btl=self,vader \
           OMPI_MCA_btl_vader_single_copy_mechanism=none mpirun

GRID    ?= coarse
NP      ?= 2

.PHONY: setup test demo bench validate faults reproduce contrast publication-mode clean

setup:
	@./scripts/bootstrap.sh

test: setup
	$(PY) -m ruff check hpcves analysis tests bench
	$(PY) -m pytest -m "not slow and not faults" -q --durations=15

demo: setup
	@mkdir -p $(DEMO)
	$(MPIRUN) -n 2 $(HPCVES) campaign jobs/demo.toml --overwrite
	$(HPCVES) status $(DEMO)/demo.h5
	$(HPCVES) analyze $(DEMO)/demo.h5 --out $(DEMO)/analysis --jobs 2
	$(PY) analysis/plot_campaign.py $(DEMO)/demo.h5 --out $(DEMO)/overview.png
	@echo "demo: $(DEMO)/demo.h5; regimes in $(DEMO)/analysis/regimes.md, phase diagram $(DEMO)/analysis/phase_diagram.png, overview $(DEMO)/overview.png"

bench: setup
	$(PY) bench/bench_solver.py --out BENCHMARKS.md
	$(PY) bench/bench_campaign.py --out BENCHMARKS.md
	$(PY) bench/bench_adaptive.py --out BENCHMARKS.md
	$(PY) bench/bench_run_loop.py --out BENCHMARKS.md
	$(PY) bench/bench_dealias.py --out BENCHMARKS.md
	$(PY) bench/bench_contrast.py --out BENCHMARKS.md
	$(PY) bench/bench_memory.py --out BENCHMARKS.md

validate: setup
	$(PY) -m pytest -m slow -q
	$(PY) analysis/validate.py --out VALIDATION.md

# kill real mpirun jobs at random moments (creation included), resume, compare bitwise (KILLS=40)
KILLS   ?= 40
faults: setup
	$(PY) -m pytest -m faults -q
	$(PY) tests/faults.py --kills $(KILLS) --out FAULTS.md

# every result of the publication (REPRODUCTION.md; resumable: run it again to continue);
# GRID=fine: tighter tolerances for a cluster (REPRODUCTION-fine.md), NP ranks;
# STUDY=name[,name]: only these campaigns, their sections rewritten, the others kept;
# RETRY_FAILED=1: their failed cases run again
STUDY   ?=
RETRY_FAILED ?=
reproduce: setup
	$(PY) analysis/reproduce.py --grid $(GRID) --np $(NP) --mpirun "$(MPIRUN)" $(if $(STUDY),--study $(STUDY)) \
	    $(if $(RETRY_FAILED),--retry-failed) \
	    --out $(if $(filter fine,$(GRID)),REPRODUCTION-fine.md,REPRODUCTION.md)

# beyond the publication (issue #42): the phase diagrams lambda x S (psi_bar = 0.5; Delta = 0.194, 0.94) and
# lambda x psi_bar (Delta = 0.94, S = 20) with a viscosity contrast, refined; their sections of REPRODUCTION.md
# (about half an hour on 2 cores; resumable like make reproduce)
CONTRAST := contrast_lambda_S_D0194,contrast_lambda_S_D094,contrast_lambda_psi
contrast: setup
	$(MAKE) reproduce STUDY=$(CONTRAST)

# the fig. 7a and 9b points where hpcves and the publication differ, in the publication's own numerics
# (preset = "publication") and in hpcves's: their sections of REPRODUCTION.md (about 50 min on 2 cores)
publication-mode: setup
	$(MAKE) reproduce STUDY=publication_mode_default,publication_mode,publication_mode_fig7a_default,publication_mode_fig7a

clean:
	rm -rf out .pytest_cache
