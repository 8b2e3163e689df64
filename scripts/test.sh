#!/usr/bin/env bash
# The project's test command (README): every test that runs on this machine.
#
# - Rust: unit, property and integration tests of the whole workspace.
#   With MICROPOS_ALL_FEATURES=1 (CI) also the V4L2 and GenICam code, which need
#   libclang-dev, libaravis-dev, libusb-1.0-0-dev and aravis-tools.
# - Python: PI's own client (PIPython) against the simulated controllers, and
#   micropos' Python client (clients/python) against microposd and the simulated
#   rig, each in a virtualenv under target/ that its script creates on first use.
# - The README followed in order from a fresh clone (scripts/newcomer.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
target=${CARGO_TARGET_DIR:-$root/target}

# Property tests draw their cases from a fixed seed, so a run is repeatable
# (a failure reproduces with the same command); set PROPTEST_RNG_SEED to
# explore other cases.
export PROPTEST_RNG_SEED="${PROPTEST_RNG_SEED:-20261127}"

features=()
if [ "${MICROPOS_ALL_FEATURES:-0}" = 1 ]; then
  features=(--all-features)
fi

# Three groups, so that no unit is compiled twice at opt-level 3 for nothing:
# - the integration tests and the CLI's unit tests, in the test profile
#   (opt-level 3: the rig tests render and decode thousands of frames);
# - hil-sim's unit tests, in the test profile too (their harness needs the
#   micropos library the first group built);
# - micropos' own unit tests in the dev profile, where micropos is at
#   opt-level 1 (Cargo.toml): they run in seconds there, and their harness,
#   the largest unit of the build, compiles in half the time.
# Dependencies are built once for all three (same settings, same target/debug).
#
# cargo-nextest, when installed, runs each group's tests in one pool (each in
# a process of its own; .config/nextest.toml), so the run does not wait on one
# binary's slowest test before the next binary starts; the doc tests, which
# nextest does not run, follow. Without it, `cargo test`. MICROPOS_NEXTEST=0
# forces `cargo test`. Each step prints the seconds since the script started,
# so a slow one shows (the build apart from the run).
step() { echo "== [${SECONDS}s] $*"; }
integration=(--workspace --bin micropos --test '*')
hil_unit=(-p hil-sim --lib)
lib_unit=(-p micropos --lib --profile dev)
if [ "${MICROPOS_NEXTEST:-1}" = 1 ] && cargo nextest --version >/dev/null 2>&1; then
  step "build the tests (cargo test --no-run ${features[*]:-}: integration, hil-sim unit, micropos unit)"
  # MICROPOS_TIMINGS=1 (CI): cargo's --timings reports, and the longest
  # units of each build printed (scripts/cargo-timings.py).
  timings=()
  if [ "${MICROPOS_TIMINGS:-0}" = 1 ]; then
    timings=(--timings)
    rm -f "$target"/cargo-timings/cargo-timing-*.html
  fi
  cargo test "${integration[@]}" "${features[@]}" "${timings[@]}" --no-run
  cargo test "${hil_unit[@]}" "${features[@]}" "${timings[@]}" --no-run
  cargo test "${lib_unit[@]}" "${features[@]}" "${timings[@]}" --no-run
  if [ ${#timings[@]} -gt 0 ]; then
    python3 scripts/cargo-timings.py "$target"/cargo-timings/cargo-timing-*.html || true
  fi
  step "cargo nextest run: integration tests and the CLI's unit tests"
  cargo nextest run "${integration[@]}" "${features[@]}"
  step "cargo nextest run: unit tests of hil-sim, then of micropos (dev profile)"
  cargo nextest run "${hil_unit[@]}" "${features[@]}"
  cargo nextest run -p micropos --lib --cargo-profile dev "${features[@]}"
  step "cargo test --doc ${features[*]:-}"
  cargo test --workspace --doc "${features[@]}"
else
  step "cargo test: integration tests and the CLI's unit tests"
  cargo test "${integration[@]}" "${features[@]}"
  step "cargo test: unit tests of hil-sim, then of micropos (dev profile)"
  cargo test "${hil_unit[@]}" "${features[@]}"
  cargo test "${lib_unit[@]}" "${features[@]}"
  step "cargo test --doc ${features[*]:-}"
  cargo test --workspace --doc "${features[@]}"
fi

# The Python suites run the hil-sim and microposd that `cargo test` just
# built (the integration tests run them too): the test profile, the
# workspace's features. Their own `cargo build -p …` would resolve features
# without the dev-dependencies and compile the library once more (12 min).
export MICROPOS_BINS_BUILT=1

step "PIPython against hil-sim"
PIPYTHON_VENV="${PIPYTHON_VENV:-$target/venv-pipython}" ./scripts/pipython.sh

step "Python client against microposd + hil-sim"
PYCLIENT_VENV="${PYCLIENT_VENV:-$target/venv-pyclient}" ./scripts/pyclient.sh

# A newcomer's first hour: a fresh clone, the README's commands in the
# order written (the main job, the served rig, the Python example), and the
# checkout left clean (scripts/newcomer.sh).
step "the README in order, from a fresh clone"
./scripts/newcomer.sh
