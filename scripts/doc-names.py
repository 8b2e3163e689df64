#!/usr/bin/env python3
"""Check that every path and name a document puts in backticks exists.

Usage: scripts/doc-names.py [--root DIR] DOC.md…

For each backticked span of each document (fenced blocks are skipped):
- a path (it contains `/` or ends in a file extension such as `.rs`,
  `.toml`, `.md`) must be a file or directory tracked by git. A path that
  does not start at the repository root is looked for under the document's
  context: in a bullet of a code map whose first backticked name is a
  directory (`- \\`driver/\\`: … \\`line.rs\\``), under that directory,
  itself under the heading's root (`### Library (\\`src/\\`)`); elsewhere
  anywhere (some tracked path ends with it, at a `/`). So a file placed
  in the wrong folder fails.
- every identifier in it (`Rig::move_to`, `daemon::{protocol, state}`,
  `MAX_PER_SOURCE`) must occur as a word in a tracked source file (not a
  Markdown one, so that a document cannot vouch for itself). Words of
  fewer than three characters and a few English words are not checked.

Prints each miss as `DOC:LINE: \\`SPAN\\`: what is missing` and exits 1 if
there is one; 0 otherwise. Python 3 standard library only; reads the file
list from `git ls-files`.
"""

import os
import re
import subprocess
import sys

SOURCE_EXT = (
    ".rs", ".py", ".toml", ".sh", ".js", ".html", ".css", ".service", ".socket",
    ".conf", ".yml", ".yaml", ".cfg", ".txt", ".json",
)
FILE_EXT = re.compile(r"\.(rs|toml|md|py|sh|conf|service|socket|js|html|css|txt)$")
IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
# Spans that are not code names: commands, flags, units, prose in code font.
SKIP_SPAN = re.compile(r"^(-|\$|cargo |micropos |microposd |hil-sim |python|git )")
ENGLISH = {
    "the", "and", "for", "not", "one", "all", "any", "its", "per", "with",
    "from", "that", "this", "only", "none", "each", "else", "true", "false",
}


def tracked(root):
    out = subprocess.run(
        ["git", "-C", root, "ls-files", "-z"], check=True, capture_output=True
    ).stdout.decode()
    files = [f for f in out.split("\0") if f]
    dirs = set()
    for f in files:
        parts = f.split("/")
        for i in range(1, len(parts)):
            dirs.add("/".join(parts[:i]) + "/")
    return files, dirs


def words_of(root, files):
    words = set()
    for f in files:
        # Sources, and extension-less scripts (.ci/run); never Markdown.
        base = f.rsplit("/", 1)[-1]
        if f.endswith(".md") or not (f.endswith(SOURCE_EXT) or "." not in base):
            continue
        try:
            with open(os.path.join(root, f), encoding="utf-8") as fh:
                words.update(IDENT.findall(fh.read()))
        except (UnicodeDecodeError, OSError):
            continue
    return words


def spans(text):
    """(line number, span, heading, bullet's first span) for each backticked span."""
    heading = ""
    bullet_first = None
    fence = False
    for n, line in enumerate(text.splitlines(), 1):
        if line.startswith("```"):
            fence = not fence
            continue
        if fence:
            continue
        if line.startswith("#"):
            heading = line
            bullet_first = None
        elif line.startswith("- ") or not line.startswith(" "):
            bullet_first = None
        # Double-backtick spans (``a `b` c``) are prose quotes: drop them.
        line = re.sub(r"``.*?``", "", line)
        for m in re.finditer(r"`([^`]+)`", line):
            s = m.group(1)
            if bullet_first is None and line.startswith("- `") and m.start() == 2:
                bullet_first = s
            yield n, s, heading, bullet_first


def heading_root(heading):
    m = re.search(r"\(`([^`]+/)`", heading)
    return m.group(1) if m else ""


def path_exists(p, files, dirs, base):
    """p from the root, or (with base) under base at any depth, or (without)
    at the end of some tracked path."""
    p = p.rstrip(".,;:")
    if p in files or p.rstrip("/") + "/" in dirs:
        return True
    suffix = "/" + p
    cands = list(files) + [d for d in dirs] if p.endswith("/") else files
    for f in cands:
        if (base == "" or f.startswith(base)) and ("/" + f).endswith(suffix):
            return True
    return False


def looks_like_path(s):
    """A repository path: not a route (`/metrics`), an absolute path, or a
    placeholder (`DIR/x`, `LOG.csv`)."""
    return (" " not in s and not s.startswith("/") and not re.match(r"^[A-Z_]+[/.]", s) and ("/" in s or FILE_EXT.search(s))
            and not s.startswith(("http", "/dev/", "/etc/", "/run/", "/tmp/", "/proc/"))
            and "::" not in s and "*" not in s and "{" not in s)


def check(doc, root, files, dirs, words):
    with open(doc, encoding="utf-8") as fh:
        text = fh.read()
    misses = []
    for n, s, heading, first in spans(text):
        if SKIP_SPAN.match(s):
            continue
        if s.startswith("./"):
            s = s[2:]
        if looks_like_path(s):
            base = heading_root(heading)
            if first and first != s and first.endswith("/") and looks_like_path(first):
                if not first.startswith(base):
                    base += first
                else:
                    base = first
            if not path_exists(s, files, dirs, base):
                where = f" under {base}" if base else ""
                misses.append(f"{doc}:{n}: `{s}`: no tracked path{where}")
            continue
        for w in IDENT.findall(s):
            if len(w) < 3 or w.lower() in ENGLISH or w.isdigit():
                continue
            if w not in words:
                misses.append(f"{doc}:{n}: `{s}`: `{w}` occurs in no source file")
    return misses


def main(argv):
    root = "."
    if len(argv) > 2 and argv[1] == "--root":
        root = argv[2]
        argv = argv[:1] + argv[3:]
    docs = argv[1:]
    if not docs:
        print(__doc__, file=sys.stderr)
        return 2
    files, dirs = tracked(root)
    words = words_of(root, files)
    misses = []
    for d in docs:
        misses += check(os.path.join(root, d) if not os.path.isabs(d) else d, root, files, dirs, words)
    for m in misses:
        print(m)
    if misses:
        print(f"doc-names: {len(misses)} names or paths in backticks do not exist "
              "(fix the document, or the name if it was renamed)", file=sys.stderr)
        return 1
    print(f"doc-names: every backticked path and name of {', '.join(docs)} exists")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
