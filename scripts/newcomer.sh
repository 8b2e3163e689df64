#!/usr/bin/env bash
# A newcomer's first hour, scripted: a fresh clone, the README's shell blocks
# in the order written, its Python example against the rig those blocks
# serve, and at the end a checkout as clean as the clone was.
#
# What is run is read from README.md itself (scripts/readme_blocks.py), so a
# README example that stops working fails here. Rules:
# - `cargo run [--release] (-p hil-sim | --bin NAME) -- ARGS` runs the binary
#   already built (MICROPOS_BINS_BUILT=1: the ones scripts/test.sh's cargo
#   test built; else `cargo build --release` first): the same program, no
#   second build;
# - `/tmp/rig` and `/tmp/micropos-venv` become directories of this run (in
#   the clone's config/microposd-sim.toml too), so a rig of the user's own
#   is never touched;
# - `./scripts/test.sh` is skipped (it is what runs this), and so is a
#   command already run once (the README shows the main job twice);
# - a block after an HTML comment `<!-- newcomer: skip (why) -->` is
#   skipped (it needs a real rig or /etc);
# - processes a block starts with `&` are stopped at the end.
# Every command must exit 0; each runs under a time limit.
#
# Called by scripts/test.sh; runnable alone from the repository root (it
# then clones HEAD: commit what it should see).
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
target=${CARGO_TARGET_DIR:-$root/target}

if [ "${MICROPOS_BINS_BUILT:-0}" = 1 ]; then
  bins=$target/debug
else
  (cd "$root" && cargo build --release --quiet -p micropos -p hil-sim --bins)
  bins=$target/release
fi
for b in hil-sim microposd micropos; do
  [ -x "$bins/$b" ] || { echo "newcomer: $bins/$b is not built" >&2; exit 1; }
done

work=$(mktemp -d "${TMPDIR:-/tmp}/micropos-newcomer.XXXXXX")
cleanup() {
  local p
  for p in $(cat "$work/pids" 2>/dev/null); do kill "$p" 2>/dev/null || true; done
  # The daemon halts the axes and exits on SIGTERM; give it a moment.
  sleep 0.5
  rm -rf "$work"
}
trap cleanup EXIT

if [ -n "$(git -C "$root" status --porcelain --untracked-files=no)" ]; then
  echo "newcomer: note: uncommitted changes are not in the clone (it is of HEAD)"
fi
git clone -q "$root" "$work/clone"
cd "$work/clone"

rig=$work/rig
venv=$work/venv
sed -i "s|/tmp/rig|$rig|g" config/microposd-sim.toml

# The README's blocks, translated, one command per line (tab-separated:
# kind, text); python blocks as one base64 line.
python3 "$root/scripts/readme_blocks.py" README.md "$bins" "$rig" "$venv" >"$work/plan"

n=0
while IFS=$'\t' read -r kind text; do
  n=$((n + 1))
  case $kind in
    skip)
      echo "== [$n] skipped: $text"
      ;;
    sh)
      echo "== [$n] \$ $text"
      if [[ $text == *'&' ]]; then
        # A background process: its output to a file, its pid kept.
        bash -c "${text%&} >>'$work/bg.log' 2>&1 & echo \$! >>'$work/pids'"
      else
        if ! timeout 600 bash -c "$text"; then
          echo "newcomer: command $n failed: $text" >&2
          tail -n 30 "$work/bg.log" 2>/dev/null | sed 's/^/background: /' >&2 || true
          exit 1
        fi
      fi
      ;;
    python)
      echo "== [$n] python (the README's example)"
      printf '%s' "$text" | base64 -d >"$work/example.py"
      if ! timeout 600 "$venv/bin/python" "$work/example.py"; then
        echo "newcomer: the README's Python example failed" >&2
        tail -n 30 "$work/bg.log" 2>/dev/null | sed 's/^/background: /' >&2 || true
        exit 1
      fi
      ;;
  esac
done <"$work/plan"

# The checkout as the clone left it: nothing written, ignored files too
# (a Python build's build/ and *.egg-info), except the rig paths above.
dirty=$(git status --porcelain --ignored | grep -v ' config/microposd-sim.toml$' || true)
if [ -n "$dirty" ]; then
  echo "newcomer: the README's commands wrote into the checkout:" >&2
  echo "$dirty" >&2
  exit 1
fi
echo "newcomer: $n steps of the README in order, checkout clean"
