# Two commands do everything on a fresh Debian machine:
#   make demo   -- set up (apt + .venv + parallel h5py, once), run a short case and plot it
#   make test   -- set up, then the test suite (what CI runs)
# Further: make bench (BENCHMARKS.md, ~1 min), make validate (VALIDATION.md, ~2 min).

PY      := .venv/bin/python
HPCVES  := .venv/bin/hpcves
DEMO    := out/demo

.PHONY: setup test demo bench validate clean

setup:
	@./scripts/bootstrap.sh

test: setup
	$(PY) -m pytest -m "not slow" -q

demo: setup
	@mkdir -p $(DEMO)
	$(HPCVES) run jobs/demo_case.toml --out $(DEMO)/case.h5 --overwrite
	$(PY) analysis/plot_case.py $(DEMO)/case.h5 --out $(DEMO)/case.png
	@echo "demo: $(DEMO)/case.h5 and $(DEMO)/case.png"

bench: setup
	$(PY) bench/bench_solver.py --out BENCHMARKS.md

validate: setup
	$(PY) -m pytest -m slow -q
	$(PY) analysis/validate.py --out VALIDATION.md

clean:
	rm -rf out .pytest_cache
