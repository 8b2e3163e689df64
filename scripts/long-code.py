#!/usr/bin/env python3
"""Lists the Rust files over N lines of non-test code; exits 1 if any is.

Non-test code is the part of a file before its test module: the lines
before the first column-0 `#[cfg(test)]` whose item is a `mod` (the
`#[cfg(test)] mod tests` convention). Test files (under a `tests/` or
`benches/` folder, `fuzz/`, or named `tests.rs`) are left out: test code
is exempt, as it is from clippy's `too_many_lines`.

A ratchet like clippy's `#[expect(clippy::too_many_lines)]`: the files in
KNOWN may stay over the limit, and the script fails once one of them no
longer is (so the list can only shrink) as well as for any other file
over it. Functions are clippy's job (`too_many_lines` at 150).

    python3 scripts/long-code.py            # the limit, 900
    python3 scripts/long-code.py -n 600     # list files over 600
"""

import argparse
import os
import re
import subprocess
import sys

# Files allowed over the limit, each with why (none since issue 35: a
# file that grows past the limit is split by job, or named here).
KNOWN = {}

TEST_DIRS = {"tests", "benches", "fuzz", "target"}
CFG_TEST = re.compile(r"^#\[cfg\(test\)\]\s*$")
MOD_ITEM = re.compile(r"^(pub(\([^)]*\))?\s+)?mod\s")


def non_test_lines(text):
    """Lines before the test module (all of them if it has none)."""
    lines = text.splitlines()
    for i, line in enumerate(lines):
        if not CFG_TEST.match(line):
            continue
        # The item the attribute is on: skip further attributes and blanks.
        for nxt in lines[i + 1 :]:
            s = nxt.strip()
            if not s or s.startswith("#["):
                continue
            if MOD_ITEM.match(nxt):
                return i
            break
    return len(lines)


def is_test_file(path):
    parts = path.split("/")
    return parts[-1] == "tests.rs" or any(p in TEST_DIRS for p in parts[:-1])


def rust_files(root):
    try:
        out = subprocess.run(
            ["git", "ls-files", "*.rs"],
            cwd=root,
            check=True,
            capture_output=True,
            text=True,
        ).stdout
        return sorted(out.split())
    except (OSError, subprocess.CalledProcessError):
        found = []
        for d, dirs, files in os.walk(root):
            dirs[:] = [x for x in dirs if x not in {".git", "target"}]
            for f in files:
                if f.endswith(".rs"):
                    found.append(os.path.relpath(os.path.join(d, f), root))
        return sorted(found)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("-n", type=int, default=900, help="the limit (900)")
    args = ap.parse_args()
    root = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
    over = {}
    for path in rust_files(root):
        if is_test_file(path):
            continue
        with open(os.path.join(root, path), encoding="utf-8") as f:
            n = non_test_lines(f.read())
        if n > args.n:
            over[path] = n
    bad = False
    for path, n in sorted(over.items(), key=lambda kv: -kv[1]):
        known = args.n == 900 and path in KNOWN
        print(f"{n:6} {path}" + ("  (known: " + KNOWN[path] + ")" if known else ""))
        bad |= not known
    if args.n == 900:
        for path in sorted(set(KNOWN) - set(over)):
            print(f"{path} is no longer over {args.n} lines: take it out of KNOWN")
            bad = True
    if bad:
        print(
            f"files over {args.n} lines of non-test code: split them by job"
            " (one job per file, each opening with a //! header)",
            file=sys.stderr,
        )
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
