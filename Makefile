# Georef developer entry points. `make run` and `make test` are the two set-up commands of the README.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
UI     := frontend/dist/index.html

.PHONY: install run test lint test-python test-frontend bench clean

$(STAMP): pyproject.toml scripts/install_system_deps.sh
	bash scripts/install_system_deps.sh
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip wheel
	$(PY) -m pip install -q -e '.[dev]'
	$(PY) -m georef_core.warmup    # compiles the numba kernels into their cache now (minutes), not in the first solve
	$(PY) -m georef_core.gnss.aot_build || echo "georef aot: not built; the solve uses numba's JIT cache"   # the GNSS kernels ahead of time (minutes): `georef gnss solve` without numba
	touch $(STAMP)

$(UI): frontend/package.json frontend/package-lock.json $(shell find frontend/src frontend/index.html frontend/vite.config.ts -type f 2>/dev/null)
	cd frontend && npm ci --no-audit --no-fund --loglevel=error && npm run build

# the Python environment and the browser UI are independent: built side by side (two jobs)
install:
	@$(MAKE) --no-print-directory -j2 $(STAMP) $(UI)
	@if [ -f georef_core/gnss/_gnss_kernels_aot.json ]; then $(PY) -m georef_core.gnss.aot_build --if-stale; fi   # kernels edited since the build: compile them again (a build that failed for want of a compiler is not retried)

# The embedded shape: SQLite, local file storage, an in-process Celery worker; the demo site is processed on first start.
run: install
	@$(PY) -m georef_core.warmup --check >/dev/null || $(PY) -m georef_core.warmup   # edited kernels: compile them again now
	$(PY) -m backend.serve_embedded

test: lint test-frontend test-python

lint: install
	$(PY) -m ruff check --select F,E9 georef_core backend worker tests bench scripts

test-python: install
	$(PY) -m pytest -q -n 2 --durations=30 tests

test-frontend: install
	cd frontend && npx vitest run --reporter=dot

bench: install
	$(PY) bench/gnss_vs_rtklib.py

clean:
	rm -rf $(VENV) work_out frontend/node_modules frontend/dist
