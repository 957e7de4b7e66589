# Georef developer entry points. `make run` and `make test` are the two set-up commands of the README.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: install run test bench clean

$(STAMP): pyproject.toml scripts/install_system_deps.sh
	bash scripts/install_system_deps.sh
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip wheel
	$(PY) -m pip install -q -e '.[dev]'
	touch $(STAMP)

install: $(STAMP)

run: install
	$(PY) -m georef_core.cli.main demo --out work_out/demo

test: install
	$(PY) -m pytest -q -n 2 tests

bench: install
	$(PY) bench/gnss_vs_rtklib.py

clean:
	rm -rf $(VENV) work_out
