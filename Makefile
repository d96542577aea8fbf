# Two commands on a fresh machine with Python 3.10+ and make:
#   make demo   - venv, install, build the FMUs, run the default scenario, log + plot in results/demo/
#   make test   - same set-up, then the test suite
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp

.PHONY: install build demo test bench clean

$(STAMP): pyproject.toml setup.py
	$(PY) -c 'import sys; assert sys.version_info >= (3, 10), "immersim needs Python >= 3.10, found " + sys.version'
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e ".[dev,dask]"
	touch $(STAMP)

install: $(STAMP)

build: install
	$(BIN)/immersim build

demo: build
	mkdir -p results/demo
	$(BIN)/immersim run scenarios/demo.toml -o results/demo/demo.mcap
	$(BIN)/immersim plot results/demo/demo.mcap 'platform.pose.*' 'platform.stroke*' -o results/demo/demo.png

test: build
	$(BIN)/python -m pytest -q -p no:cacheprovider tests

bench: build
	$(BIN)/python benchmarks/run_all.py

clean:
	rm -rf build .venv
