#!/usr/bin/env bash
# The Python client (clients/python, package `micropos`) against the real
# microposd and `hil-sim serve`: pytest in a virtualenv, the package installed
# the way users install it (`pip install ./clients/python`).
# Called by scripts/test.sh (the README test command); runnable alone from the repository root.
#
# Env: PYCLIENT_VENV (default $CARGO_TARGET_DIR/venv-pyclient), CARGO_TARGET_DIR
# (default target); extra arguments go to pytest (e.g. -k async -x).
set -euo pipefail
cd "$(dirname "$0")/.."

target="${CARGO_TARGET_DIR:-$PWD/target}"
venv="${PYCLIENT_VENV:-$target/venv-pyclient}"
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
fi
# Reinstalled on every run: the tests must exercise the current sources as
# installed, not a stale copy in site-packages.
"$venv/bin/pip" install --quiet --disable-pip-version-check --force-reinstall --no-deps ./clients/python
"$venv/bin/pip" install --quiet --disable-pip-version-check "pytest>=7"

# MICROPOS_BINS_BUILT=1 (scripts/test.sh): the binaries in $target/debug
# are the ones `cargo test --workspace` built; run alone, this builds them.
if [ "${MICROPOS_BINS_BUILT:-0}" != 1 ]; then
    cargo build --quiet -p micropos -p hil-sim --bins
fi
export MICROPOSD_BIN="$target/debug/microposd"
export HIL_SIM_BIN="$target/debug/hil-sim"
# From clients/python so its pytest settings apply; the installed package,
# not the source tree, is what the tests import (src/ layout).
cd clients/python
"$venv/bin/python" -m pytest -q -p no:cacheprovider "$@" tests
