#!/usr/bin/env bash
# One-time (idempotent) setup: system renderer, virtual environment, torch, LIBERO, vlaprobe.
# Re-runs are a no-op unless this script or pyproject.toml changed.
# Usage: bash scripts/setup.sh         everything: what running needs, and the tests' and linters' tools (make test)
#        bash scripts/setup.sh --run   what `vlaprobe run` needs only (make run): no test tools, Chromium, Prolog, g++
set -euo pipefail
cd "$(dirname "$0")/.."

LEVEL=dev
if [[ "${1:-}" == "--run" ]]; then
    LEVEL=run
elif [[ -n "${1:-}" ]]; then
    echo "setup: unknown option $1; use no option (everything) or --run (what vlaprobe run needs)" >&2
    exit 2
fi
VENV=${VLAPROBE_VENV:-.venv}
PY=${PYTHON:-python3}
STAMP="$VENV/.vlaprobe-setup"  # "<hash of this script and pyproject.toml> <level installed: run or dev>"
want=$(cat scripts/setup.sh pyproject.toml | sha256sum | cut -c1-16)
# The web UI: installs web/node_modules (npm ci: the vitest tests need them) and rebuilds src/vlaprobe/live/ui
# when web/ changed. Without Node the committed build is served; the script checks its own stamp, so it runs on
# every setup. For a run, only a stale build needs Node.
if command -v node >/dev/null && command -v npm >/dev/null; then
    if [[ "$LEVEL" == dev ]] || ! bash scripts/build_web.sh --check >/dev/null 2>&1; then
        bash scripts/build_web.sh || echo "setup: building the web UI failed; the shipped build in src/vlaprobe/live/ui is served" >&2
    fi
fi
have_hash="" have_level=""
[[ -f "$STAMP" ]] && { read -r have_hash have_level < "$STAMP" || true; }
if [[ "$have_hash" == "$want" && ("$have_level" == dev || "$LEVEL" == run) ]]; then
    exit 0
fi

# System packages (Debian/Ubuntu), installed with apt when run as root:
# - libosmesa6: offscreen rendering without a GPU (OSMesa; Mesa's EGL is the fallback);
# - swi-prolog-nox: runs the DIARC-syntax Prolog rules of the cognition in the tests (vlaprobe.cognition);
# - chromium: the browser of the web UI's end-to-end test (Playwright drives /usr/bin/chromium).
# - g++: the C++ compiler torch.compile's CPU backend builds its kernels with (`vlaprobe finetune --compile`).
need=()
ldconfig -p 2>/dev/null | grep -q libOSMesa || need+=(libosmesa6)
if [[ "$LEVEL" == dev ]]; then
    command -v swipl >/dev/null || need+=(swi-prolog-nox)
    [[ -x /usr/bin/chromium ]] || need+=(chromium)
    command -v g++ >/dev/null || need+=(g++)
fi
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

# torch first, pinned to one release. Where no NVIDIA GPU is present: the CPU build (on Linux x86-64 pinned as
# `+cpu`, so no resolve can fall back to the CUDA wheel of the default index, several GB). torch's CPU wheel index
# is asked once, quickly (one try, a few seconds, in a subprocess a timeout ends): pip would retry an
# unreachable index with back-off for torch and each of its dependencies. When it does not answer, the CPU
# wheel comes from pip's configured sources (a mirror, PIP_FIND_LINKS); VLAPROBE_TORCH_INDEX names another
# index ("" never asks one).
TORCH=2.13.0
TORCH_INDEX=${VLAPROBE_TORCH_INDEX-https://download.pytorch.org/whl/cpu}
answers() {  # answers URL: the index serves its torch page in time (one try; `timeout` also bounds the DNS look-up)
    local limit=()
    command -v timeout >/dev/null && limit=(timeout 10)
    "${limit[@]}" "$VENV/bin/python" - "$1" <<'PY' >/dev/null 2>&1
import sys, urllib.request
urllib.request.urlopen(sys.argv[1].rstrip("/") + "/torch/", timeout=5).close()
PY
}
if ! "$VENV/bin/python" -c "import torch" 2>/dev/null; then
    if command -v nvidia-smi >/dev/null 2>&1; then
        "${PIP[@]}" "torch==$TORCH"
    else
        spec="torch==$TORCH"
        [[ "$(uname -sm)" == "Linux x86_64" ]] && spec="torch==$TORCH+cpu"
        if [[ -n "$TORCH_INDEX" ]] && answers "$TORCH_INDEX"; then
            "${PIP[@]}" "$spec" --extra-index-url "$TORCH_INDEX"
        else
            # The probe can miss a proxy only pip knows: then pip asks the index itself, with one retry.
            echo "setup: ${TORCH_INDEX:-no torch index (VLAPROBE_TORCH_INDEX is empty)}${TORCH_INDEX:+ did not answer}; $spec from pip's configured sources"
            "${PIP[@]}" "$spec" \
                || { [[ -n "$TORCH_INDEX" ]] && "${PIP[@]}" --retries 1 "$spec" --extra-index-url "$TORCH_INDEX"; } \
                || {
                    echo "setup: $spec is in none of pip's sources; make the index ${TORCH_INDEX:-of torch CPU wheels} reachable, set VLAPROBE_TORCH_INDEX to a mirror of it, or put the wheel in a folder named by PIP_FIND_LINKS" >&2
                    exit 1
                }
        fi
    fi
fi

# LIBERO and its simulator stack, at the pins of pyproject.toml's `libero` extra (read from there: one source),
# without their declared dependencies: libero 0.1.1 declares hydra, wandb, transformers, robomimic, thop, einops,
# ... that `libero.libero` never imports. What it does import is in pyproject.toml's dependencies (with the
# mujoco pin and why).
mapfile -t libero_pins < <("$VENV/bin/python" - <<'PY'
import re
extra = re.search(r"^libero = \[(.*?)\]", open("pyproject.toml").read(), re.M | re.S)
print("\n".join(re.findall(r'"([^"]+)"', extra.group(1))) if extra else "")
PY
)
if [[ -z "${libero_pins[0]:-}" ]]; then
    echo "setup: pyproject.toml has no \`libero = [...]\` extra; restore it" >&2
    exit 1
fi
"${PIP[@]}" --no-deps "${libero_pins[@]}"

# pip lists the packages libero declares but never imports (hydra, wandb, robomimic...) as missing: expected.
if [[ "$LEVEL" == dev ]]; then
    "${PIP[@]}" -e ".[dev,ray]"
else
    "${PIP[@]}" -e .
fi

echo "$want $LEVEL" > "$STAMP"
echo "setup: done ($VENV)"
