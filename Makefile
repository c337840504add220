# Imitation-BT: `make figures` and `make test` are all the set-up a fresh machine needs.
SHELL := /bin/bash
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
NOTEBOOKS := $(sort $(wildcard notebooks/[0-9]*.ipynb))
export SDL_VIDEODRIVER := dummy
export PYTHONHASHSEED := 0

.DEFAULT_GOAL := help
.PHONY: bench-pipeline mutants help setup check-dot figures animations reproduce smoke test test-slow lint lab lock clean distclean book verify

help: ## list the targets
	@grep -E '^[a-zA-Z_-]+:.*## ' $(MAKEFILE_LIST) | awk -F':.*## ' '{printf "  make %-10s %s\n", $$1, $$2}'

$(STAMP): environment.lock pyproject.toml | check-dot
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -r environment.lock
	$(BIN)/python -m pip install --quiet --no-deps -e .
	@touch $(STAMP)

setup: $(STAMP) check-dot ## create .venv from environment.lock (reinstalls only when the lock changed)

check-dot: ## fail with a hint when graphviz's dot is missing
	@command -v dot >/dev/null || { echo "graphviz's 'dot' is missing: install it with 'sudo apt-get install graphviz' (Debian/Ubuntu) or 'brew install graphviz' (macOS)"; exit 1; }

figures: setup ## re-run every notebook (paper profile, cached results) and rewrite figures/ and paper/
	@set -e; start=$$(date +%s); rm -rf build/cache-reads; mkdir -p build/cache-reads; \
	for nb in $(NOTEBOOKS); do \
		echo "== $$nb"; \
		IBT_PROFILE=paper IBT_CACHE_READS=$(CURDIR)/build/cache-reads \
			$(BIN)/python -m ibt.notebooks run $$nb; \
	done; \
	$(BIN)/python -m ibt.notebooks record-time $$(( $$(date +%s) - start )); \
	$(BIN)/python -m ibt.cache.admin stale --reads build/cache-reads --count  # what this run skipped, in one line

animations: setup ## the GIFs of Behavior Trees in motion, figures/anim/*.gif (about a minute)
	@start=$$(date +%s); nice -n 10 $(BIN)/python -m ibt.views.animate --out figures/anim; \
	echo "make animations: $$(( $$(date +%s) - start )) s"

reproduce: setup ## recompute everything from scratch: experts, grids, figures (hours; resumable)
	@mkdir -p build/reproduce && test -f build/reproduce/started || touch build/reproduce/started
	@echo "Last time on this kind of machine each stage took (an estimate; progress bars follow):"
	@$(BIN)/python -c "from ibt.report.stats import Results; from ibt.report.tables import timings_markdown; from ibt.paths import DATA_DIR; print(timings_markdown(Results(DATA_DIR), with_record=True))"
	$(BIN)/python -m ibt train --refresh-before build/reproduce/started
	$(BIN)/python -m ibt random-baselines
	IBT_CACHE_DIR=$(CURDIR)/build/reproduce/cache $(MAKE) figures
	rm -f build/reproduce/started

bench-pipeline: setup ## time `python -m ibt pipeline` on users' tasks and committed experts (data/results/pipeline_bench.csv; an hour with LunarLander)
	PYTHONPATH=$(CURDIR) $(BIN)/python -m tests.bench_pipeline $(CASES)

mutants: setup ## mutation testing of the core, on demand (Cosmic Ray, sampled, one worker: docs/mutation.md)
	@start=$$(date +%s); nice -n 15 $(BIN)/python -m tests.mutation $(MODULES); \
	echo "make mutants: $$(( $$(date +%s) - start )) s"

smoke: setup ## run every notebook under the smoke profile into build/smoke (seconds each)
	@mkdir -p build/smoke
	@set -e; for nb in $(NOTEBOOKS); do \
		IBT_PROFILE=smoke $(BIN)/papermill --no-progress-bar --cwd notebooks $$nb build/smoke/$$(basename $$nb); \
	done

verify: setup ## check every headline and verdict number against paper/claims.csv: OK or the difference (SMOKE=1: a few rows)
	@start=$$(date +%s); $(BIN)/python -m ibt.check_claims $(if $(SMOKE),--smoke) && \
	echo "make verify: $$(( $$(date +%s) - start )) s"

book: setup ## the HTML book (notebooks with their committed outputs, paper/, docs/, CLI, API), offline
	@$(BIN)/python -m ibt.book notebooks $(NOTEBOOKS) || exit 2  # a broken notebook: one line
	@start=$$(date +%s); $(BIN)/sphinx-build -q -W --keep-going -b html -c docs/book \
		-d build/book/doctrees . build/book/html && \
	echo "make book: $$(( $$(date +%s) - start )) s; open build/book/html/index.html" \
		"(check it: $(BIN)/python -m ibt.book check build/book/html)"

lint: setup ## ruff, mypy (the package) and the import-layer contract (pyproject.toml)
	$(BIN)/ruff check ibt tests notebooks
	$(BIN)/mypy
	$(BIN)/lint-imports --no-cache

test: setup lint ## ruff + unit/property tests + every notebook under the smoke profile (nbval)
	$(BIN)/python -m pytest -m "not slow" -q
	@rm -rf build/smoke-scratch
	IBT_PROFILE=smoke IBT_SMOKE_DIR=$(CURDIR)/build/smoke-scratch $(BIN)/python -m pytest --nbval-lax -q notebooks
	@rm -rf build/smoke-scratch  # nbval kills its kernels, so their own scratch folders would stay

test-slow: setup ## the slow tests too (training determinism, full-size runs)
	$(BIN)/python -m pytest -q

lab: setup ## open JupyterLab on the notebooks (also as root, or headless: open the URL it prints)
	@flags="--no-browser"; \
	if [ -n "$$DISPLAY$$WAYLAND_DISPLAY" ] || [ "$$(uname)" = Darwin ]; then flags=""; fi; \
	if [ "$$(id -u)" = 0 ]; then flags="$$flags --allow-root"; fi; \
	echo "JupyterLab: open the http://localhost:8888/lab?token=... URL printed below in a browser (Ctrl-C stops it)"; \
	$(BIN)/jupyter lab $$flags notebooks

lock: ## re-resolve requirements.in into environment.lock (in a scratch venv)
	rm -rf build/lockenv && $(PYTHON) -m venv build/lockenv
	build/lockenv/bin/python -m pip install --quiet --upgrade pip
	build/lockenv/bin/python -m pip install --quiet -r requirements.in
	{ echo "# Generated by \`make lock\` from requirements.in; every package pinned, transitive ones too."; \
	  echo "# torch is the CPU build (pip picks it from the local wheel cache or the PyTorch CPU index)."; \
	  build/lockenv/bin/python -m pip freeze | sed 's/^torch==\(.*\)+cpu$$/torch==\1/'; } > environment.lock
	rm -rf build/lockenv

clean: ## remove scratch files (build/, caches); keeps .venv and committed data
	rm -rf build .pytest_cache .ruff_cache .hypothesis .mypy_cache
	find . -name __pycache__ -not -path './.venv/*' -prune -exec rm -rf {} +

distclean: clean ## also remove .venv
	rm -rf $(VENV)
