#!/usr/bin/env bash
# Builds the web UI (web/) into the Python package (src/vlaprobe/live/ui/) when the committed build is stale.
# The build ships in the package, so `pip install` needs no Node; this script only matters after editing web/.
# Stale = the sha256 of the web sources (see web_sources below) differs from src/vlaprobe/live/ui/BUILD_STAMP.
# `npm ci` runs first when web/node_modules is missing or older than package-lock.json.
# Usage: bash scripts/build_web.sh [--check | --stamp]
#   --check: only report, exit 1 when stale;  --stamp: write the stamp (the last step of `npm run build`).
set -euo pipefail
cd "$(dirname "$0")/../web"

STAMP=../src/vlaprobe/live/ui/BUILD_STAMP

# The files the build depends on, relative to web/, in byte order (tests/web/test_build.py hashes the same).
web_sources() {
    { find src -type f; printf '%s\n' index.html package.json package-lock.json tsconfig.json vite.config.ts; } | LC_ALL=C sort
}
sources_hash() {
    web_sources | while IFS= read -r f; do printf '%s  %s\n' "$(sha256sum < "$f" | cut -c1-64)" "$f"; done | sha256sum | cut -c1-64
}

want=$(sources_hash)
if [[ "${1:-}" == "--stamp" ]]; then
    printf '%s\n' "$want" > "$STAMP"
    exit 0
fi
have=$(cat "$STAMP" 2>/dev/null || true)
if [[ "${1:-}" == "--check" ]]; then
    if [[ "$want" == "$have" ]]; then
        echo "build_web: src/vlaprobe/live/ui is up to date ($want)"
        exit 0
    fi
    echo "build_web: src/vlaprobe/live/ui is stale (stamp ${have:-missing}, sources $want): run bash scripts/build_web.sh" >&2
    exit 1
fi
node_major=$(node -p 'process.versions.node.split(".")[0]' 2>/dev/null || echo 0)
if ! command -v npm >/dev/null || ((node_major < 20)); then
    # Vite 8 needs Node 20.19+; without it the committed build is served unchanged.
    [[ "$want" == "$have" ]] || echo "build_web: web/ changed but Node 20+ with npm is missing; install it to rebuild the UI (the shipped build is served meanwhile)" >&2
    exit 0
fi

# Dependencies: exactly the lockfile's versions (also what `npm test` in `make test` needs).
if [[ ! -f node_modules/.package-lock.json || package-lock.json -nt node_modules/.package-lock.json ]]; then
    echo "build_web: npm ci"
    npm ci --no-audit --no-fund --loglevel=error
fi
if [[ "$want" != "$have" ]]; then
    echo "build_web: building the UI into src/vlaprobe/live/ui"
    npm run --silent build >/dev/null  # ends with `build_web.sh --stamp`
fi
