# The two commands of the README. Both run the (idempotent) setup first.
.PHONY: setup setup-run run test lint bench ui

# LIBERO's assets: $VLAPROBE_LIBERO_ASSETS when set, else a shared copy beside the checkout when there is one
# (offline machines), else LIBERO downloads them itself on first use.
ifeq ($(origin VLAPROBE_LIBERO_ASSETS), undefined)
  ifneq ($(wildcard ../shared/libero_assets/scenes),)
    export VLAPROBE_LIBERO_ASSETS := $(abspath ../shared/libero_assets)
  endif
endif

# Everything: what running needs, and the tests' and linters' tools.
setup:
	@bash scripts/setup.sh

# What `vlaprobe run` needs only (a no-op after `make setup`).
setup-run:
	@bash scripts/setup.sh --run

run: setup-run
	.venv/bin/vlaprobe run

# The web UI's unit tests (vitest) run too where Node is installed (setup ran `npm ci` then).
# pytest in two passes: the tests marked `serial` (timed, or a browser + server + simulator) alone, then the
# rest on two pytest-xdist workers with one torch/BLAS thread each (tests/conftest.py), file by file so a
# module's fixtures are built once, the files marked `heavy` (minutes of simulator episodes) first. Both passes run even if the first fails; the second's summary closes the output.
test: setup
	@if command -v npm >/dev/null; then cd web && npm test --silent; else echo "make test: npm missing, web unit tests skipped"; fi
	@status=0; \
	.venv/bin/pytest -q -m serial || status=$$?; \
	OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 .venv/bin/pytest -q -m "not serial" -n 2 --dist loadfile || status=$$?; \
	exit $$status

# Rebuild the web UI into src/vlaprobe/live/ui when web/ changed (setup does this too).
ui:
	@bash scripts/build_web.sh

# ruff (lint and format) on the Python trees, mypy on src/ (configured in pyproject.toml), ESLint on web/src
# where Node is installed.
lint: setup
	.venv/bin/ruff check src tests bench scripts
	.venv/bin/ruff format --check src tests bench scripts
	.venv/bin/mypy
	@if command -v npm >/dev/null; then cd web && npm run --silent lint; else echo "make lint: npm missing, ESLint skipped"; fi
