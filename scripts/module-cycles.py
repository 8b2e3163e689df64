#!/usr/bin/env python3
"""Print the module import cycles of the workspace's library crates.

A file imports another when it names a path into it: `use crate::a::b`,
`use super::x`, `use self::y`, grouped `use crate::{a, b::{c, d}}`, or a
`crate::a::b::f(..)` / `super::f(..)` path in code. A path is resolved to the
file of the longest module prefix that exists (`foo.rs` or `foo/mod.rs`); a
name that module re-exports with `pub use` is followed to the file that
defines it, so `crate::daemon::Rig` counts as an import of `daemon/rig.rs`,
not of `daemon/mod.rs`. `mod x;` declarations are not imports.

A `pub use` is not itself an import (it is followed where it is used).
Test-only code is left out unless `--tests` is given: inline `#[cfg(test)]`
modules and files declared under `#[cfg(test)] mod x;`.

Output: one strongly connected component of the file graph per line (two
files that import each other, or a longer ring), its files sorted, then the
count. Crates: `micropos` (src/) and `hil_sim` (hil-sim/src/); binaries
(`src/bin/`, `hil-sim/src/main.rs`) are separate crates and are not read.
Python 3 standard library only; always exits 0.

Usage: scripts/module-cycles.py [--tests] [--edges] [REPO_ROOT]
  --tests  also read test-only code
  --edges  after each crate, the pairs of files that import each other
"""

import os
import re
import sys

CRATES = [("micropos", "src"), ("hil_sim", "hil-sim/src")]


def strip_comments_and_strings(text):
    """Blanks comments, string and char literals (keeps line structure)."""
    out = []
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            i = j
        elif text.startswith("/*", i):
            depth, j = 1, i + 2
            while j < n and depth:
                if text.startswith("/*", j):
                    depth, j = depth + 1, j + 2
                elif text.startswith("*/", j):
                    depth, j = depth - 1, j + 2
                else:
                    j += 1
            out.append("\n" * text.count("\n", i, j))
            i = j
        elif c == "r" and re.match(r'r#*"', text[i:i + 40]) and (
            i == 0 or not (text[i - 1].isalnum() or text[i - 1] == "_")
        ):
            m = re.match(r'r(#*)"', text[i:])
            end = '"' + m.group(1)
            j = text.find(end, i + m.end())
            j = n if j < 0 else j + len(end)
            out.append('""' + "\n" * text.count("\n", i, j))
            i = j
        elif c == '"':
            j = i + 1
            while j < n and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            j += 1
            out.append('""' + "\n" * text.count("\n", i, j))
            i = j
        elif c == "'":
            # char literal ('a', '\n', '\u{..}') or a lifetime ('a)
            m = re.match(r"'(\\u\{[0-9a-fA-F]+\}|\\.|[^\\'])'", text[i:])
            if m:
                out.append("' '")
                i += m.end()
            else:
                out.append(c)
                i += 1
        else:
            out.append(c)
            i += 1
    return "".join(out)


def inline_test_blocks(code, keep):
    """Inline `#[cfg(test)] mod name { .. }` blocks (rustfmt layout: the block
    ends at the first `}` line with the `mod` line's indent): blanked, or with
    `keep` kept and their `super::` read as the file's own module."""
    lines = code.split("\n")
    out = []
    skip_indent = None
    pending_cfg_test = False
    for line in lines:
        if skip_indent is not None:
            if line.rstrip() == skip_indent + "}":
                skip_indent = None
            out.append(re.sub(r"\bsuper::", "self::", line) if keep else "")
            continue
        stripped = line.strip()
        m = re.match(r"(\s*)(pub(\([^)]*\))?\s+)?mod\s+\w+\s*\{", line)
        if m and pending_cfg_test:
            skip_indent = m.group(1)
            out.append(line if keep else "")
            pending_cfg_test = False
            continue
        if stripped.startswith("#[cfg(test)]"):
            pending_cfg_test = True
        elif stripped and not stripped.startswith("#["):
            pending_cfg_test = False
        out.append(line)
    return "\n".join(out)


TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*|::|[{},;*]|\S")


def parse_paths(code, children=()):
    """Returns (is_pub_use, path segments, alias) for every crate/super/self
    path and every path that starts with a child module's name (`tie::f`,
    read as `self::tie::f`): use trees expanded, code paths as written."""
    toks = TOKEN.findall(code)
    n = len(toks)

    def tree(i, prefix, pub, acc):
        # parses a use tree at toks[i]; appends full paths to acc
        segs = list(prefix)
        while i < n:
            t = toks[i]
            if t == "{":
                i += 1
                while i < n and toks[i] != "}":
                    i = tree(i, segs, pub, acc)
                    if i < n and toks[i] == ",":
                        i += 1
                return i + 1
            if t == "*":
                acc.append((pub, segs + ["*"], None))
                return i + 1
            if re.match(r"[A-Za-z_]", t):
                segs.append(t)
                i += 1
                if i < n and toks[i] == "::":
                    i += 1
                    continue
                alias = None
                if i + 1 < n and toks[i] == "as":
                    alias = toks[i + 1]
                    i += 2
                acc.append((pub, segs, alias))
                return i
            return i + 1
        return i

    out = []
    i = 0
    while i < n:
        t = toks[i]
        if t == "use":
            pub = i > 0 and (toks[i - 1] == "pub" or toks[i - 1] == ")")
            acc = []
            j = tree(i + 1, [], pub, acc)
            for pub_, segs, alias in acc:
                if segs and segs[0] in ("crate", "super", "self"):
                    out.append((pub_, segs, alias))
                elif len(segs) > 1 and segs[0] in children:
                    out.append((pub_, ["self"] + segs, alias))
            i = j
            continue
        child = t in children and (i == 0 or toks[i - 1] != "::")
        if (t in ("crate", "super") or child) and i + 1 < n and toks[i + 1] == "::":
            segs = ["self", t] if child else [t]
            j = i + 2
            while j < n and re.match(r"[A-Za-z_]", toks[j]):
                segs.append(toks[j])
                if j + 1 < n and toks[j + 1] == "::":
                    j += 2
                else:
                    j += 1
                    break
            out.append((False, segs, None))
            i = j
            continue
        i += 1
    return out


def module_of(rel):
    """src-relative file path -> module path tuple."""
    parts = rel[:-3].split(os.sep)
    if parts[-1] in ("mod", "lib"):
        parts = parts[:-1]
    return tuple(parts)


def load_crate(root, tests):
    files = {}
    for dirpath, dirnames, filenames in os.walk(root):
        rel_dir = os.path.relpath(dirpath, root)
        if rel_dir.split(os.sep)[0] == "bin":
            continue
        for f in filenames:
            if not f.endswith(".rs"):
                continue
            rel = os.path.normpath(os.path.join(rel_dir, f))
            if rel == "main.rs":
                continue
            with open(os.path.join(dirpath, f), encoding="utf-8") as fh:
                files[module_of(rel)] = (rel, fh.read())
    # modules declared under #[cfg(test)]
    test_mods = set()
    for mod, (rel, text) in files.items():
        for m in re.finditer(r"#\[cfg\(test\)\]\s*(?:pub(?:\([^)]*\))?\s+)?mod\s+(\w+)\s*;", text):
            test_mods.add(mod + (m.group(1),))
    if not tests:
        files = {
            m: v for m, v in files.items()
            if not any(m[: len(t)] == t for t in test_mods)
        }
    code = {}
    for mod, (rel, text) in files.items():
        c = strip_comments_and_strings(text)
        code[mod] = inline_test_blocks(c, tests)
    return files, code


def absolute(mod, segs):
    """Resolves crate/super/self prefixes against module `mod`."""
    base = list(mod)
    k = 0
    if segs[0] == "crate":
        base, k = [], 1
    else:
        while k < len(segs) and segs[k] in ("super", "self"):
            if segs[k] == "super":
                base = base[:-1]
            k += 1
    return tuple(base) + tuple(segs[k:])


def build_graph(files, code):
    children = {m: set() for m in files}
    for m in files:
        if m:
            children.setdefault(m[:-1], set()).add(m[-1])
    paths = {m: parse_paths(c, children.get(m, set())) for m, c in code.items()}
    # re-exports: module -> {name: absolute target path}
    reexports = {}
    for m, ps in paths.items():
        table = {}
        for pub, segs, alias in ps:
            if pub and segs[-1] != "*":
                table[alias or segs[-1]] = absolute(m, segs)
        reexports[m] = table
    # `pub use` of a sibling/child module path written without a prefix
    # (`pub use rig::Rig;` in mod.rs) is not a crate/super/self path: read it.
    for m, c in code.items():
        for mm in re.finditer(r"\bpub\s+use\s+([A-Za-z_][\w:]*)(?:\s+as\s+(\w+))?\s*;", c):
            segs = mm.group(1).split("::")
            if segs[0] in ("crate", "super", "self") or len(segs) < 2:
                continue
            if m + (segs[0],) in files:
                reexports[m][mm.group(2) or segs[-1]] = m + tuple(segs)
        for mm in re.finditer(r"\bpub\s+use\s+(\w+)::\{([^}]*)\}\s*;", c):
            if m + (mm.group(1),) not in files:
                continue
            for item in mm.group(2).split(","):
                item = item.strip()
                if not item or "{" in item:
                    continue
                parts = item.split(" as ")
                segs = [mm.group(1)] + parts[0].strip().split("::")
                name = parts[1].strip() if len(parts) > 1 else segs[-1]
                reexports[m][name] = m + tuple(segs)

    def resolve(path, depth=0):
        for k in range(len(path), -1, -1):
            prefix = path[:k]
            if prefix in files:
                rest = path[k:]
                if rest and depth < 8 and rest[0] in reexports.get(prefix, {}):
                    target = reexports[prefix][rest[0]] + rest[1:]
                    if target != path:
                        return resolve(target, depth + 1)
                return prefix
        return None

    graph = {m: set() for m in files}
    for m, ps in paths.items():
        for pub, segs, alias in ps:
            if pub:
                continue  # a re-export: followed where it is used
            p = absolute(m, [s for s in segs if s != "*"])
            t = resolve(p)
            if t is not None and t != m:
                graph[m].add(t)
    return graph


def sccs(graph):
    index, low, on, stack, out = {}, {}, set(), [], []
    counter = [0]

    def visit(v):
        work = [(v, iter(sorted(graph[v])))]
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        while work:
            node, it = work[-1]
            advanced = False
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter[0]
                    counter[0] += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                    advanced = True
                    break
                if w in on:
                    low[node] = min(low[node], index[w])
            if advanced:
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                comp = []
                while True:
                    w = stack.pop()
                    on.discard(w)
                    comp.append(w)
                    if w == node:
                        break
                if len(comp) > 1:
                    out.append(comp)

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def main(argv):
    tests = "--tests" in argv
    edges = "--edges" in argv
    args = [a for a in argv if not a.startswith("--")]
    repo = args[0] if args else os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
    total = 0
    for crate, rel_root in CRATES:
        root = os.path.join(repo, rel_root)
        if not os.path.isdir(root):
            continue
        files, code = load_crate(root, tests)
        graph = build_graph(files, code)
        name = {m: os.path.join(rel_root, files[m][0]) for m in files}
        comps = sorted(sorted(name[m] for m in c) for c in sccs(graph))
        for comp in comps:
            print("%s: %s" % (crate, " ".join(comp)))
        if edges:
            for m in sorted(graph):
                for t in sorted(graph[m]):
                    if m < t and m in graph.get(t, ()):
                        print("  %s <-> %s" % (name[m], name[t]))
        total += len(comps)
    print("%d cycle%s" % (total, "" if total == 1 else "s"))
    return 0


if __name__ == "__main__":
    try:
        main(sys.argv[1:])
    except BrokenPipeError:
        pass
    sys.exit(0)
