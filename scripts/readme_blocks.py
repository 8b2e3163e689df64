#!/usr/bin/env python3
"""The README's runnable blocks as a plan for scripts/newcomer.sh.

Usage: readme_blocks.py README.md BINS RIG_DIR VENV_DIR

Prints one step per line, `kind<TAB>text`: `sh` (one shell command, the
README's `cargo run` rewritten to the built binary in BINS), `python` (a
whole ```python block, base64), `skip` (why a command or block is not run).
`/tmp/rig` and `/tmp/micropos-venv` are replaced by RIG_DIR and VENV_DIR.
Exits 2 when the README has no shell block (a parse gone wrong must not
pass as an empty plan).
"""

import base64
import re
import sys

CARGO_RUN = re.compile(
    r"^cargo run(?: --release)? (?:-p (?P<pkg>\S+)|--bin (?P<bin>\S+))(?: --release)? -- ?(?P<args>.*)$"
)
SKIP = re.compile(r"<!--\s*newcomer:\s*skip\s*\(?(?P<why>.*?)\)?\s*-->")
# A trailing comment: whitespace, `#`, whitespace (the README puts no `#`
# inside quotes on a command line).
COMMENT = re.compile(r"\s+#\s.*$")


def blocks(text):
    """(language, lines, skip reason or None) for each fenced block."""
    lines = text.splitlines()
    i = 0
    last_text = ""
    while i < len(lines):
        line = lines[i]
        m = re.match(r"^```(\w*)\s*$", line)
        if not m:
            if line.strip():
                last_text = line
            i += 1
            continue
        lang = m.group(1)
        body = []
        i += 1
        while i < len(lines) and not lines[i].startswith("```"):
            body.append(lines[i])
            i += 1
        i += 1
        s = SKIP.search(last_text)
        yield lang, body, (s.group("why") or "marked") if s else None
        last_text = ""


def commands(body):
    """Shell commands of a block: continuation lines joined, comments gone."""
    cmd = ""
    for raw in body:
        line = raw.rstrip()
        if not cmd and (not line.strip() or line.lstrip().startswith("#")):
            continue
        if line.endswith("\\"):
            cmd += line[:-1] + " "
            continue
        cmd += line
        yield COMMENT.sub("", cmd).strip()
        cmd = ""
    if cmd:
        yield COMMENT.sub("", cmd).strip()


def main():
    if len(sys.argv) != 5:
        print(__doc__, file=sys.stderr)
        return 2
    readme, bins, rig, venv = sys.argv[1:]
    with open(readme, encoding="utf-8") as f:
        text = f.read()

    def local(s):
        return s.replace("/tmp/micropos-venv", venv).replace("/tmp/rig", rig)

    seen = set()
    shell_blocks = 0
    out = []
    for lang, body, skip in blocks(text):
        if lang in ("sh", "bash", "shell"):
            shell_blocks += 1
            for c in commands(body):
                if skip:
                    out.append(("skip", f"{c} ({skip})"))
                    continue
                if c == "./scripts/test.sh":
                    out.append(("skip", f"{c} (the test command runs this)"))
                    continue
                m = CARGO_RUN.match(c)
                if m:
                    name = m.group("pkg") or m.group("bin")
                    c = f"{bins}/{name} {m.group('args')}".rstrip()
                c = local(c)
                if c in seen:
                    out.append(("skip", f"{c} (already run above)"))
                    continue
                seen.add(c)
                out.append(("sh", c))
        elif lang == "python":
            if skip:
                out.append(("skip", f"a python block ({skip})"))
                continue
            code = local("\n".join(body) + "\n")
            out.append(("python", base64.b64encode(code.encode()).decode()))
    if shell_blocks == 0:
        print("readme_blocks: no shell block in the README", file=sys.stderr)
        return 2
    for kind, t in out:
        if "\t" in t or "\n" in t:
            print(f"readme_blocks: a step holds a tab or newline: {t!r}", file=sys.stderr)
            return 2
        print(f"{kind}\t{t}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
