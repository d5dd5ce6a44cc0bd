# One-command set-up: every target creates .venv and installs kx with its pinned dependencies first.
PY := .venv/bin/python
STAMP := .venv/.kx-installed

.PHONY: run test test-slow install-check bench calibrate lint

$(STAMP): pyproject.toml
	python3 -m venv .venv
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev]'
	$(PY) -m kx.hyperneat.native || true  # HyperNEAT's native decision kernel into the per-user cache (optional: one line says why not)
	touch $(STAMP)

run: $(STAMP)  ## the main job
	$(PY) -m kx.train

test: $(STAMP)  ## the default test suite (what CI runs)
	$(PY) -m pytest -q -n 2 --dist loadfile --no-loadscope-reorder

install-check: $(STAMP)  ## kx as a wheel in a fresh environment outside the checkout: the main job and a protocol run
	.ci/install-check $(PY)

test-slow: $(STAMP)  ## the long tests
	$(PY) -m pytest -q -n 2 --dist loadfile --no-loadscope-reorder -m slow

bench: $(STAMP)  ## every benchmark of python -m kx.bench, one after another (long: one is python -m kx.bench NAME)
	$(PY) -m pip install -q -e '.[dev,bench]'  # neat_xor's optional baseline, neat-python
	for name in $$($(PY) -c 'from kx.bench.__main__ import BENCHES; print(*BENCHES)'); do \
		echo "== python -m kx.bench $$name"; $(PY) -m kx.bench $$name || exit 1; \
	done

calibrate: $(STAMP)
	$(PY) scripts/calibrate.py

lint: $(STAMP)
	$(PY) -m ruff check kx tests scripts
