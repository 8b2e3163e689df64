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
# - The documents against the code: every path and name ARCHITECTURE.md puts
#   in backticks exists (scripts/doc-names.py), the README quotes only
#   figures docs/results.md holds, and that file's `--short` section is what
#   a fresh `hil-sim run --short --json --seed 1` gives (scripts/results.py).
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

# cargo-nextest, when installed, runs every test of both packages in one pool
# (each in a process of its own; .config/nextest.toml), so the run does not
# wait on one binary's slowest test before the next binary starts; the doc
# tests, which nextest does not run, follow. Without it, `cargo test`.
# MICROPOS_NEXTEST=0 forces `cargo test`. Each step prints the seconds since
# the script started, so a slow one shows (the build apart from the run).
#
# One build for all the tests: a second cargo invocation (another profile,
# or one package) resolves features for its own selection and compiles the
# library again (measured: the library's unit tests at opt-level 1 in the dev
# profile cost 104 s after the main build, the library rebuilt for hil-sim's
# unit tests alone 102 s, against the lib-test harness at opt-level 3
# compiled beside the library within the one build).
# shellcheck source=scripts/stage.sh
. scripts/stage.sh

# Seconds, and before the build: a stale document fails at once.
stage "documents: names and paths, quoted figures"
python3 scripts/doc-names.py ARCHITECTURE.md
python3 scripts/results.py --check-quotes README.md docs/results.md

# No file over 900 lines of non-test code (clippy's too_many_lines keeps
# functions at 150): a ratchet, instant.
stage "files over 900 lines (scripts/long-code.py)"
python3 scripts/long-code.py

if [ "${MICROPOS_NEXTEST:-1}" = 1 ] && cargo nextest --version >/dev/null 2>&1; then
  stage "build the tests (cargo test --no-run ${features[*]:-})"
  # MICROPOS_TIMINGS=1 (CI): cargo's --timings report, and the build's
  # longest units printed (scripts/cargo-timings.py).
  timings=()
  if [ "${MICROPOS_TIMINGS:-0}" = 1 ]; then
    timings=(--timings)
    rm -f "$target"/cargo-timings/cargo-timing-*.html
  fi
  cargo test --workspace "${features[@]}" "${timings[@]}" --no-run
  if [ ${#timings[@]} -gt 0 ]; then
    python3 scripts/cargo-timings.py -n 12 "$target"/cargo-timings/cargo-timing-*.html || true
  fi
  stage "cargo nextest run ${features[*]:-}"
  cargo nextest run --workspace "${features[@]}"
  stage "cargo test --doc ${features[*]:-}"
  cargo test --workspace --doc "${features[@]}"
else
  stage "cargo test ${features[*]:-}"
  cargo test --workspace "${features[@]}"
fi

# The Python suites run the hil-sim and microposd that `cargo test` just
# built (the integration tests run them too): the test profile, the
# workspace's features. Their own `cargo build -p …` would resolve features
# without the dev-dependencies and compile the library once more (12 min).
export MICROPOS_BINS_BUILT=1

# Three suites run rigs in real time and leave the CPUs mostly idle
# (measured: PIPython 6 CPU-s in 20 s, the Python client 43 CPU-s in 50 s;
# the newcomer's main job uses one core): they run side by side, each into
# a log of its own, printed whole when all have ended, in this order. Each
# has its own rig, temporary directories and virtualenv; none binds a
# fixed port. The fourth, the short job against docs/results.md, takes one
# core for the seconds of a `--short` run.
#
# MICROPOS_FUZZ=1 (CI) adds the fuzz targets' smoke run (.ci/fuzz run) as a
# fifth, at idle priority: it fills the cores the real-time suites leave
# idle instead of running after them (it waits for the fuzz build, which
# .ci/run starts in the background at the beginning, on cargo's lock).
suites=(pipython pyclient newcomer results)
declare -A what=(
  [pipython]="PIPython against hil-sim"
  [pyclient]="Python client against microposd + hil-sim"
  [newcomer]="the README in order, from a fresh clone"
  [results]="docs/results.md's short section against a fresh --short run"
  [fuzz]="every fuzz target's smoke run, at idle priority"
)
if [ "${MICROPOS_FUZZ:-0}" = 1 ]; then
  suites+=(fuzz)
fi
# The short job's JSON is byte-identical per seed, so its section of
# docs/results.md must be exactly what this run gives.
check_results() {
  local json
  json=$(mktemp)
  "$target/debug/hil-sim" run --short --json --seed 1 >"$json" || { rm -f "$json"; return 1; }
  local rc=0
  python3 scripts/results.py --check-short "$json" docs/results.md || rc=$?
  rm -f "$json"
  return "$rc"
}
run_suite() {
  case $1 in
    pipython) PIPYTHON_VENV="${PIPYTHON_VENV:-$target/venv-pipython}" ./scripts/pipython.sh ;;
    pyclient) PYCLIENT_VENV="${PYCLIENT_VENV:-$target/venv-pyclient}" ./scripts/pyclient.sh ;;
    # A newcomer's first hour: a fresh clone, the README's commands in the
    # order written (the main job, the served rig, the Python example), and
    # the checkout left clean (scripts/newcomer.sh).
    newcomer) ./scripts/newcomer.sh ;;
    results) check_results ;;
    fuzz)
      local idle=(nice -n 19)
      if ionice -c 3 true 2>/dev/null; then idle+=(ionice -c 3); fi
      "${idle[@]}" .ci/fuzz run
      ;;
  esac
}
stage "side by side: ${suites[*]}"
logs=$(mktemp -d)
declare -A pid
for s in "${suites[@]}"; do
  (
    start=$SECONDS
    rc=0
    run_suite "$s" >"$logs/$s.log" 2>&1 || rc=$?
    echo "$rc $((SECONDS - start))" >"$logs/$s.end"
    exit "$rc"
  ) &
  pid[$s]=$!
done
failed=()
for s in "${suites[@]}"; do wait "${pid[$s]}" || failed+=("$s"); done
for s in "${suites[@]}"; do
  read -r rc secs <"$logs/$s.end" || { rc="?"; secs="?"; }
  echo "== ${what[$s]} (exit $rc, ${secs} s)"
  cat "$logs/$s.log"
done
rm -rf "$logs"
if [ ${#failed[@]} -gt 0 ]; then
  echo "failed: ${failed[*]}" >&2
  exit 1
fi
stage "test command done"
