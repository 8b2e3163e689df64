#!/usr/bin/env bash
# The build cache .ci/run keeps between runs (a CARGO_TARGET_DIR outside the
# clone, and one for the fuzz workspace).
#
#   scripts/ci-cache.sh prune DIR
#
# Empties DIR when it holds more than MICROPOS_CI_CACHE_CAP_GB (default 12),
# else removes every artifact of this repository's own packages (the root
# workspace's and fuzz/'s: their libraries, binaries, tests, benches and
# fingerprints), so that only dependencies are reused and nothing of an
# earlier clone can stand in for this one's code. Names come from `cargo
# metadata`; a dependency of the same crate name as one of ours would be
# removed too and rebuilt (costs time, never correctness).
set -euo pipefail
cd "$(dirname "$0")/.."
[ "${1:-}" = prune ] && [ -n "${2:-}" ] || { echo "usage: $0 prune DIR" >&2; exit 2; }
dir=$2
cap_gb=${MICROPOS_CI_CACHE_CAP_GB:-12}
[ -d "$dir" ] || exit 0

used_kb=$(du -sk "$dir" | cut -f1)
if [ "$used_kb" -gt $((cap_gb * 1024 * 1024)) ]; then
  echo "build cache: $((used_kb / 1024 / 1024)) GB > ${cap_gb} GB, emptied"
  find "$dir" -mindepth 1 -maxdepth 1 -exec rm -rf {} +
  exit 0
fi

# Package names (fingerprint folders) and crate names (files in deps/) of
# both workspaces, one per line.
names() {
  local manifest
  for manifest in Cargo.toml fuzz/Cargo.toml; do
    [ -f "$manifest" ] || continue
    cargo metadata --no-deps --format-version 1 --manifest-path "$manifest" 2>/dev/null
    echo
  done | python3 -c '
import json, sys
out = set()
for line in sys.stdin:
    line = line.strip()
    if not line:
        continue
    for p in json.loads(line)["packages"]:
        out.add("fp " + p["name"])
        for t in p["targets"]:
            out.add("crate " + t["name"].replace("-", "_"))
print("\n".join(sorted(out)))
'
}

removed=0
while read -r kind name; do
  case $kind in
    fp) pattern="^${name}-[0-9a-f]{16}\$"; sub=.fingerprint ;;
    crate) pattern="^(lib)?${name}-[0-9a-f]{16}(\\..*)?\$"; sub=deps ;;
    *) continue ;;
  esac
  while IFS= read -r -d '' d; do
    while IFS= read -r f; do
      rm -rf "${d:?}/$f"
      removed=$((removed + 1))
    done < <(ls -A "$d" | grep -E "$pattern" || true)
  done < <(find "$dir" -type d -name "$sub" -print0)
done < <(names)
echo "build cache: removed $removed artifacts of this repository's own packages"
