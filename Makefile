# The two commands of the README. Both run the (idempotent) setup first.
.PHONY: setup run test lint bench ui

# LIBERO's assets: $VLAPROBE_LIBERO_ASSETS when set, else a shared copy beside the checkout when there is one
# (offline machines), else LIBERO downloads them itself on first use.
ifeq ($(origin VLAPROBE_LIBERO_ASSETS), undefined)
  ifneq ($(wildcard ../shared/libero_assets/scenes),)
    export VLAPROBE_LIBERO_ASSETS := $(abspath ../shared/libero_assets)
  endif
endif

setup:
	@bash scripts/setup.sh

run: setup
	.venv/bin/vlaprobe run

# The web UI's unit tests (vitest) run too where Node is installed (setup ran `npm ci` then).
# vitest first, so that pytest's summary closes the output.
test: setup
	@if command -v npm >/dev/null; then cd web && npm test --silent; else echo "make test: npm missing, web unit tests skipped"; fi
	.venv/bin/pytest -q

# Rebuild the web UI into src/vlaprobe/live/ui when web/ changed (setup does this too).
ui:
	@bash scripts/build_web.sh

lint: setup
	.venv/bin/ruff check src tests bench
	.venv/bin/ruff format --check src tests bench
