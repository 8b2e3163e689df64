#!/usr/bin/env bash
# PI's official Python client (PIPython) against the simulated C-863s.
# Called by scripts/test.sh (the README test command); runnable alone from the repository root.
#
# Env: PIPYTHON_VENV (default .venv-pipython), CARGO_TARGET_DIR (default target).
set -euo pipefail
cd "$(dirname "$0")/.."

venv="${PIPYTHON_VENV:-.venv-pipython}"
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
fi
# Pinned: the simulator is checked against this PIPython release.
"$venv/bin/pip" install --quiet --disable-pip-version-check \
    "PIPython==2.11.0.6" "pyserial==3.5" "pytest>=7"

# MICROPOS_BINS_BUILT: see scripts/pyclient.sh.
if [ "${MICROPOS_BINS_BUILT:-0}" != 1 ]; then
    cargo build --quiet -p hil-sim --bin hil-sim
fi
export HIL_SIM_BIN="${CARGO_TARGET_DIR:-target}/debug/hil-sim"
"$venv/bin/python" -m pytest -q tests/pipython
