# One-command set-up: every target creates .venv and installs kx with its pinned dependencies first.
PY := .venv/bin/python
STAMP := .venv/.kx-installed

.PHONY: run test test-slow bench calibrate lint

$(STAMP): pyproject.toml
	python3 -m venv .venv
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev]'
	touch $(STAMP)

run: $(STAMP)  ## the main job
	$(PY) -m kx.train

test: $(STAMP)  ## the default test suite (what CI runs)
	$(PY) -m pytest -q -n 2 --dist loadfile --no-loadscope-reorder

test-slow: $(STAMP)  ## the long tests
	$(PY) -m pytest -q -n 2 --dist loadfile --no-loadscope-reorder -m slow

bench: $(STAMP)  ## every benchmark (neat_xor also installs the optional neat-python baseline)
	$(PY) -m pip install -q -e '.[dev,bench]'
	$(PY) -m kx.bench sim
	$(PY) -m kx.bench neat_xor
	$(PY) -m kx.bench neat_generation
	$(PY) -m kx.bench generation
	$(PY) -m kx.bench runs
	$(PY) -m kx.bench learning

calibrate: $(STAMP)
	$(PY) scripts/calibrate.py

lint: $(STAMP)
	$(PY) -m ruff check kx tests scripts
