#!/usr/bin/env bash
# Creates .venv and installs companion; `bootstrap.sh train` also installs the torch export/training extra
# (the tests need it for the Monodepth2 exporter round trip). Called by scripts/demo and scripts/test.
# `bootstrap.sh train test-tools` (scripts/test) also installs the Debian readers the output tests run (exiftool,
# gdalinfo, and chromium for the map viewer, driven by playwright from the dev extra) when it runs as root with
# apt-get (CI); anyone else is told the command and the tests that need them fail with the same fix.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
want="${1:-runtime}"
extra="${2:-}"
py="${PYTHON:-python3}"
if ! command -v "$py" >/dev/null; then
    echo "error: $py not found. fix: install Python 3.11+ (apt-get install python3 python3-venv)" >&2; exit 2
fi
if ! "$py" -c 'import sys; sys.exit(sys.version_info < (3, 11))'; then
    echo "error: $("$py" --version) is too old. fix: install Python 3.11+ (or set PYTHON=python3.11)" >&2; exit 2
fi
if [ ! -x .venv/bin/python ]; then
    if ! "$py" -m venv .venv 2>/dev/null; then
        rm -rf .venv
        if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
            echo "python3-venv missing: installing it with apt-get" >&2
            apt-get update -qq && apt-get install -y -qq python3-venv >/dev/null
            "$py" -m venv .venv
        else
            echo "error: cannot create .venv. fix: sudo apt-get install python3-venv" >&2; exit 2
        fi
    fi
fi
stamp=".venv/.companion-installed-$want"
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
    .venv/bin/python -m pip install -q --upgrade pip >/dev/null
    if [ "$want" = train ]; then
        # The CPU build of torch (a plain `pip install torch` would pull GBs of CUDA wheels).
        .venv/bin/python -m pip install -q "torch==2.13.0"
        .venv/bin/python -m pip install -q -e ".[dev,train]"
    else
        .venv/bin/python -m pip install -q -e ".[dev]"
    fi
    touch "$stamp"
fi
if [ "$extra" = test-tools ]; then
    missing=""
    command -v exiftool >/dev/null || missing="$missing libimage-exiftool-perl"
    command -v gdalinfo >/dev/null || missing="$missing gdal-bin"
    command -v chromium >/dev/null || missing="$missing chromium"
    if [ -n "$missing" ]; then
        if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
            echo "installing the output readers the tests use:$missing" >&2
            apt-get update -qq && apt-get install -y -qq $missing >/dev/null
        else
            echo "warning: the output tests need:$missing. fix: sudo apt-get install -y$missing" >&2
        fi
    fi
fi
