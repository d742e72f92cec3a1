#!/usr/bin/env bash
# One-time (idempotent) setup: system renderer, virtual environment, torch, LIBERO, vlaprobe.
# Re-runs are a no-op unless this script or pyproject.toml changed. Usage: bash scripts/setup.sh
set -euo pipefail
cd "$(dirname "$0")/.."

VENV=${VLAPROBE_VENV:-.venv}
PY=${PYTHON:-python3}
STAMP="$VENV/.vlaprobe-setup"
want=$(cat scripts/setup.sh pyproject.toml | sha256sum | cut -c1-16)
# The web UI: installs web/node_modules (npm ci) and rebuilds src/vlaprobe/live/ui when web/ changed. Without
# Node the committed build is served; the script checks its own stamp, so it runs on every setup.
if command -v node >/dev/null && command -v npm >/dev/null; then
    bash scripts/build_web.sh || echo "setup: building the web UI failed; the shipped build in src/vlaprobe/live/ui is served" >&2
fi
if [[ -f "$STAMP" && "$(cat "$STAMP")" == "$want" ]]; then
    exit 0
fi

# System packages (Debian/Ubuntu), installed with apt when run as root:
# - libosmesa6: offscreen rendering without a GPU (OSMesa; Mesa's EGL is the fallback);
# - swi-prolog-nox: runs the DIARC-syntax Prolog rules of the cognition in the tests (vlaprobe.cognition);
# - chromium: the browser of the web UI's end-to-end test (Playwright drives /usr/bin/chromium).
# - g++: the C++ compiler torch.compile's CPU backend builds its kernels with (`vlaprobe finetune --compile`).
need=()
ldconfig -p 2>/dev/null | grep -q libOSMesa || need+=(libosmesa6)
command -v swipl >/dev/null || need+=(swi-prolog-nox)
[[ -x /usr/bin/chromium ]] || need+=(chromium)
command -v g++ >/dev/null || need+=(g++)
if ((${#need[@]})); then
    if command -v apt-get >/dev/null && [[ $(id -u) == 0 ]]; then
        echo "setup: installing ${need[*]} (apt)"
        (apt-get install -y -qq "${need[@]}" >/dev/null 2>&1) || (apt-get update -qq && apt-get install -y -qq "${need[@]}" >/dev/null)
    else
        echo "setup: missing system packages ${need[*]}; install them with apt (rendering falls back to EGL; the Prolog and browser tests are skipped; the --compile test needs g++)" >&2
    fi
fi

if [[ ! -x "$VENV/bin/python" ]]; then
    "$PY" -m venv "$VENV"
fi
PIP=("$VENV/bin/python" -m pip install --disable-pip-version-check -q)

# torch first, pinned to one release: the CPU build where no NVIDIA GPU is present. A bare `torch`
# requirement would pull several GB of CUDA packages.
if ! "$VENV/bin/python" -c "import torch" 2>/dev/null; then
    if command -v nvidia-smi >/dev/null 2>&1; then
        "${PIP[@]}" torch==2.13.0
    else
        "${PIP[@]}" torch==2.13.0 --extra-index-url https://download.pytorch.org/whl/cpu
    fi
fi

# LIBERO and its simulator stack without their declared dependencies: libero 0.1.1 declares hydra, wandb,
# transformers, robomimic, thop, einops, ... that `libero.libero` never imports. What it does import is
# listed in pyproject.toml (with the mujoco pin and why).
"${PIP[@]}" --no-deps libero==0.1.1 bddl==1.0.1 robosuite==1.4.0

# pip lists the packages libero declares but never imports (hydra, wandb, robomimic...) as missing: expected.
"${PIP[@]}" -e ".[dev,ray]"

echo "$want" > "$STAMP"
echo "setup: done ($VENV)"
