#!/usr/bin/env python3
"""The slowest compilation units of cargo builds, from their `--timings` reports.

    scripts/cargo-timings.py [-n N] REPORT.html ...

Prints, per report, the build's wall time and its N longest units (wall
seconds each unit took, which on a busy machine includes waiting for a
core), so a CI log shows where the build time goes. Python 3, stdlib only.
"""
import argparse
import json
import re
import sys


def units(path):
    with open(path, encoding="utf-8") as f:
        html = f.read()
    m = re.search(r"const UNIT_DATA = (\[.*?\]);", html, re.S)
    if not m:
        raise ValueError(f"{path}: no UNIT_DATA (not a cargo --timings report?)")
    return json.loads(m.group(1))


def describe(u):
    target = u.get("target", "").strip()
    mode = u.get("mode", "")
    what = f"{u['name']} {target}".strip()
    return f"{what} ({mode})" if mode and mode != "todo" else what


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=8, help="units to list per report")
    ap.add_argument("reports", nargs="+")
    args = ap.parse_args()
    for path in args.reports:
        try:
            data = units(path)
        except (OSError, ValueError) as e:
            print(f"cargo-timings: {e}", file=sys.stderr)
            return 1
        if not data:
            print(f"{path}: nothing compiled")
            continue
        end = max(u["start"] + u["duration"] for u in data)
        print(f"{path}: {len(data)} units, {end:.0f} s wall")
        for u in sorted(data, key=lambda u: -u["duration"])[: args.n]:
            print(f"  {u['duration']:7.1f} s  {describe(u)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
