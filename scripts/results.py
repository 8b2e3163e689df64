#!/usr/bin/env python3
"""Write docs/results.md from the main job's JSON, or check it against a run.

Every measured figure the project quotes lives in docs/results.md, and
every figure there is read from the JSON of a run by this script: nothing
is typed in by hand. The file is made of sections, each between
`<!-- results:begin NAME -->` and `<!-- results:end NAME -->`, each from
one kind of run:

  main     hil-sim run --json --seed 1                (--main FILE)
  kinder   hil-sim run --json --seed 1 --model config/stage-model.toml
                                                      (--kinder FILE)
  seeds    hil-sim run --json --seed N, N = 1..5      (--seeds FILE…)
  paper    micropos paper --seeds 5 --json --model M, M = the default
           and the paper-faithful stage model  (--paper-default F
                                                --paper-faithful F)
  short    hil-sim run --short --json --seed 1        (--short FILE)

A FILE is either the `--json` output or the `data/run.json` that `--out DIR`
writes (`{"summary": …, "wall_s": …, "phases_wall_s": …}`); from the
latter the wall time is shown too, marked as the machine's, not the seed's.

Usage:
  scripts/results.py [--main F] [--kinder F] [--seeds F…] [--short F]
                     [--commit C] [--out docs/results.md]
      Writes the file. A section whose run is not given is kept as the
      file has it (or, in a new file, says the command that makes it).
      C is the commit the runs were built from (default: `git rev-parse
      --short HEAD`), written into each section made now.
  scripts/results.py --check-short FILE.json [docs/results.md]
      Exit 0 if the file's `short` section is the one FILE.json gives;
      else print a diff and exit 1. The short section holds no commit and
      no wall time, and the JSON of a seed is byte-identical on every
      machine, so the comparison is exact.

Python 3 standard library only.
"""

import argparse
import difflib
import hashlib
import json
import os
import re
import statistics
import subprocess
import sys

MODES = ["raw", "table", "model", "closed_loop"]
TESTS = ["square", "random"]
# The paper's AP (Tan et al., sections V.B and V.C): not measured here.
PAPER_AP_UM = {("square", "raw"): "22", ("random", "raw"): "22",
               ("square", "table"): "3.5", ("random", "table"): "7"}
COMMANDS = {
    "main": "hil-sim run --json --seed 1",
    "kinder": "hil-sim run --json --seed 1 --model config/stage-model.toml",
    "seeds": "hil-sim run --json --seed N   (N = 1, 2, 3, 4, 5)",
    "paper": "micropos paper --seeds 5 --json --model config/stage-model.toml "
             "(and config/stage-model-paper.toml)",
    "short": "hil-sim run --short --json --seed 1",
}
TITLES = {
    "main": "The main job, paper-faithful stage, seed 1",
    "kinder": "The main job, kinder stage, seed 1",
    "seeds": "The main job, paper-faithful stage, seeds 1–5",
    "paper": "The paper's statements at model level (`micropos paper`)",
    "short": "The short job (`--short`), seed 1",
}
# The main job's phases in the order they run (`phases_s` is sorted by name).
PHASES = ["reference", "charact-paper", "charact-short", "tables", "validate",
          "validate_drift_off", "validate_drift_static", "validate_drift_adaptive",
          "sweep", "grid"]
ORDER = ["main", "kinder", "seeds", "paper", "short"]
BEGIN = "<!-- results:begin {} -->"
END = "<!-- results:end {} -->"


class Missing(Exception):
    """A figure the JSON does not hold."""


def get(v, *path):
    for k in path:
        if isinstance(v, dict) and k in v:
            v = v[k]
        elif isinstance(v, list) and isinstance(k, int) and k < len(v):
            v = v[k]
        else:
            return None
    return v


def num(v, digits):
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return "–"
    return f"{v:.{digits}f}"


def g(v):
    """A given (not measured) value as written: 22, 3.5, 0.25."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return "–"
    return f"{v:g}"


def um(v):
    return num(v, 3)


def load(path):
    """(summary, wall or None, sha256 of the summary without wall fields)."""
    with open(path, "rb") as f:
        raw = f.read()
    data = json.loads(raw)
    wall = None
    if isinstance(data, dict) and "summary" in data and "wall_s" in data:
        wall = {"wall_s": data.get("wall_s"), "phases": data.get("phases_wall_s") or {}}
        data = data["summary"]
    clean = strip_wall(data)
    digest = hashlib.sha256(
        json.dumps(clean, sort_keys=True, separators=(",", ":")).encode()
    ).hexdigest()
    return clean, wall, digest


def strip_wall(v):
    """The JSON without wall-clock fields (keys naming `wall`): those depend
    on the machine, the rest only on the seed."""
    if isinstance(v, dict):
        return {k: strip_wall(x) for k, x in v.items() if "wall" not in k}
    if isinstance(v, list):
        return [strip_wall(x) for x in v]
    return v


def ap_table(s):
    out = ["| trajectory | mode | AP max µm | AP mean µm | RP max µm | RP mean µm | paper AP µm |",
           "|---|---|---|---|---|---|---|"]
    for t in TESTS:
        for m in MODES:
            r = get(s, t, m) or {}
            out.append(f"| {t} | {m} | {um(r.get('ap_um'))} | {um(r.get('ap_mean_um'))} | "
                       f"{um(r.get('rp_um'))} | {um(r.get('rp_mean_um'))} | "
                       f"{PAPER_AP_UM.get((t, m), '–')} |")
    return out


def charact_lines(s):
    c = get(s, "characterization") or {}
    out = ["| characterization | points | simulated s | settle s |", "|---|---|---|---|"]
    out.append(f"| `charact-paper` (the paper's plan; reduced with `--short`) | {c.get('points', '–')} | {num(c.get('simulated_s'), 1)} | "
               f"{num(c.get('settle_s'), 2)} |")
    out.append(f"| `charact-short` ({num(c.get('short_step_um'), 0)} µm steps, "
               f"{c.get('short_moves_per_cycle', '–')} moves of varied length per cycle) | "
               f"{c.get('short_points', '–')} | {num(c.get('short_simulated_s'), 1)} | "
               f"{num(c.get('short_settle_s'), 2)} |")
    return out


def drift_lines(s):
    d = get(s, "drift") or {}
    out = [f"Drift references every {d.get('characterization_every_s', '–')} s in the "
           f"characterizations; validation with live drift `{d.get('live', '–')}` every "
           f"{d.get('live_every_s', '–')} s."]
    cmp = d.get("compare")
    if isinstance(cmp, dict):
        out += ["", "Table mode by live drift (`drift.compare`; `off` is the paper's procedure):", "",
                "| live drift | AP max µm square / random | AP mean µm square / random | "
                "constant offset x, y µm square / random |",
                "|---|---|---|---|"]
        for m in ["off", "static", "adaptive"]:
            r = cmp.get(m) or {}
            sq, ra = r.get("square") or {}, r.get("random") or {}

            def off(x):
                o = x.get("offset_um") or [None, None]
                return f"{um(o[0])}, {um(o[1])}"
            out.append(f"| {m} | {um(sq.get('ap_um'))} / {um(ra.get('ap_um'))} | "
                       f"{um(sq.get('ap_mean_um'))} / {um(ra.get('ap_mean_um'))} | "
                       f"{off(sq)} / {off(ra)} |")
    return out


def sweep_lines(s):
    sw = get(s, "sweep")
    if not isinstance(sw, dict):
        return ["No sweep row in this run (`--short` has none)."]
    res = sw.get("result") or {}
    est = res.get("camera_delay_s")
    true = sw.get("true_delay_s")
    err = est - true if isinstance(est, (int, float)) and isinstance(true, (int, float)) else None
    anchors = res.get("anchors") or {}
    out = [f"Sweep characterization: {num(sw.get('simulated_s'), 1)} simulated s (the step plan: "
           f"{num(sw.get('step_simulated_s'), 1)} s), {anchors.get('duration_s') and num(anchors.get('duration_s'), 1) or '–'} s "
           f"of it at {anchors.get('positions', '–')} static anchor positions "
           f"({anchors.get('measured', '–')} visits); {res.get('frames', '–')} frames, "
           f"{res.get('pos_samples', '–')} position samples, {res.get('records', '–')} records.",
           "",
           f"Camera delay: estimated {num(est * 1e3 if isinstance(est, (int, float)) else None, 4)} ms, "
           f"true {num(true * 1e3 if isinstance(true, (int, float)) else None, 4)} ms "
           f"(error {'–' if err is None else f'{err * 1e3:+.4f}'} ms).",
           "",
           "| tables (validated in table mode, live drift off) | AP max µm square / random |",
           "|---|---|"]
    rows = [("step tables", "step_table_ap_um"), ("sweep tables", "run-sweep"),
            ("sweep, camera delay ignored", "run-sweep-nodelay"),
            ("sweep, no static anchors", "run-sweep-noanchor")]
    for label, k in rows:
        r = sw.get(k)
        if isinstance(r, dict):
            out.append(f"| {label} | {um(get(r, 'square', 'ap_um'))} / {um(get(r, 'random', 'ap_um'))} |")
    return out


def grid_lines(s):
    g = get(s, "grid")
    if not isinstance(g, dict):
        return ["No grid row in this run."]
    out = [f"Grid characterization at {num(g.get('pitch_um'), 0)} µm pitch: {g.get('nodes', '–')} nodes "
           f"in {num(g.get('simulated_s'), 1)} simulated s; its 2-D map validated in table mode, "
           "live drift off:",
           "",
           "| tables | AP max µm square / random | AP mean µm square / random |",
           "|---|---|---|"]
    for label, r in [("2-D grid map", g), ("step tables", g.get("step_table_ap_um") or {})]:
        out.append(f"| {label} | {um(get(r, 'square', 'ap_um'))} / {um(get(r, 'random', 'ap_um'))} | "
                   f"{um(get(r, 'square', 'ap_mean_um'))} / {um(get(r, 'random', 'ap_mean_um'))} |")
    return out


def phases_lines(s, wall):
    p = get(s, "phases_s") or {}
    total = sum(v for v in p.values() if isinstance(v, (int, float)))
    head = "| phase | simulated s |" + (" wall s (this machine) |" if wall else "")
    out = [head, "|---|---|" + ("---|" if wall else "")]
    for k in sorted(p, key=lambda k: (PHASES.index(k) if k in PHASES else len(PHASES), k)):
        v = p[k]
        row = f"| {k} | {num(v, 1)} |"
        if wall:
            row += f" {num(wall['phases'].get(k), 1)} |"
        out.append(row)
    row = f"| all | {num(total, 1)} |"
    if wall:
        row += f" {num(wall.get('wall_s'), 1)} |"
    out.append(row)
    fr = get(s, "frames") or {}
    out += ["", f"Frames grabbed {fr.get('grabbed', '–')}, decoded {fr.get('decoded', '–')}."]
    if wall:
        out += ["", "Wall time is this machine's at the time of the run (its load, its CPU), "
                "not a property of the seed; it comes from the run's `run.json`."]
    return out


def run_section(name, s, wall, digest, commit):
    out = [f'<a id="{name}"></a>', "", f"## {TITLES[name]}", "",
           f"From `{COMMANDS[name]}` (JSON sha256 `{digest[:16]}…`, wall-clock fields left out"
           + (f"; built from commit `{commit}`" if commit else "") + ").", ""]
    out += [f'<a id="{name}-ap"></a>', "", "### AP and RP per trajectory and mode", "",
            "ISO 9283 over the poses: AP max and mean, RP max and mean; the validation runs with "
            "live drift as configured below.", ""]
    out += ap_table(s) + [""]
    for part, title, lines in [("charact", "Characterizations", charact_lines(s)),
                               ("drift", "Live drift", drift_lines(s)),
                               ("sweep", "Sweep row", sweep_lines(s)),
                               ("grid", "Grid row", grid_lines(s)),
                               ("time", "Time per phase", phases_lines(s, wall))]:
        out += [f'<a id="{name}-{part}"></a>', "", f"### {title}", ""] + lines + [""]
    return out


def seeds_section(runs, commit):
    """Median [min, max] over the seeds of each headline AP."""
    out = ['<a id="seeds"></a>', "", f"## {TITLES['seeds']}", "",
           f"From `{COMMANDS['seeds']}`, {len(runs)} runs"
           + (f", built from commit `{commit}`" if commit else "") + "; median [min, max] over the seeds.",
           "",
           "| mode | AP max µm square | AP max µm random | random / square |",
           "|---|---|---|---|"]

    def stat(vals, digits=2):
        vals = [v for v in vals if isinstance(v, (int, float))]
        if not vals:
            return "–"
        return (f"{statistics.median(vals):.{digits}f} "
                f"[{min(vals):.{digits}f}, {max(vals):.{digits}f}]")

    rows = [("raw", lambda s, t: get(s, t, "raw", "ap_um")),
            ("the paper's procedure (lookup tables, live drift off)",
             lambda s, t: get(s, "drift", "compare", "off", t, "ap_um")),
            ("lookup tables, live drift adaptive", lambda s, t: get(s, t, "table", "ap_um")),
            ("model table", lambda s, t: get(s, t, "model", "ap_um")),
            ("closed loop", lambda s, t: get(s, t, "closed_loop", "ap_um")),
            ("sweep tables, live drift off", lambda s, t: get(s, "sweep", "run-sweep", t, "ap_um")),
            ("2-D grid map, live drift off", lambda s, t: get(s, "grid", t, "ap_um"))]
    for label, f in rows:
        sq = [f(s, "square") for s, _ in runs]
        ra = [f(s, "random") for s, _ in runs]
        ratio = [r / q for q, r in zip(sq, ra)
                 if isinstance(q, (int, float)) and isinstance(r, (int, float)) and q]
        digits = 3 if label == "closed loop" else 2
        out.append(f"| {label} | {stat(sq, digits)} | {stat(ra, digits)} | {stat(ratio)} |")
    out += ["", "Runs (seed order): " + ", ".join(f"`{d[:12]}…`" for _, d in runs), ""]
    return out


def paper_section(default, faithful, commit):
    """Each statement of the paper beside the two models' medians."""
    out = ['<a id="paper"></a>', "", f"## {TITLES['paper']}", "",
           f"From `{COMMANDS['paper']}`"
           + (f", built from commit `{commit}`" if commit else "")
           + ": the paper's procedure on the stage model alone (no camera, no daemon), "
           "median [min, max] over seeds 1–5; ✓ when the median lies in the accepted range.", "",
           "| statement | paper | accepted | default model | paper-faithful model |",
           "|---|---|---|---|---|"]
    by_id = {}
    for label, data in [("default", default), ("faithful", faithful)]:
        for c in data.get("statements") or []:
            by_id.setdefault(get(c, "statement", "id"), {})[label] = c
    for sid, cs in by_id.items():
        st = (cs.get("default") or cs.get("faithful"))["statement"]
        lo, hi = st.get("accept") or [None, None]

        def fig(c):
            if not c:
                return "–"
            sp = c.get("spread") or [None, None]
            mark = "✓" if c.get("holds") else "✗"
            return f"{num(c.get('median'), 3)} [{num(sp[0], 3)}, {num(sp[1], 3)}] {mark}"
        unit = f" {st['unit']}" if st.get("unit") else ""
        accepted = (f"≥ {g(lo)}" if hi is None else f"≤ {g(hi)}" if lo is None
                    else f"{g(lo)}–{g(hi)}")
        out.append(f"| `{sid}`: {st.get('text', '')} | {g(st.get('paper'))}{unit} | "
                   f"{accepted}{unit} | {fig(cs.get('default'))} | {fig(cs.get('faithful'))} |")
    runs = (faithful.get("runs") or [])
    hours = [r.get("characterization_s") / 3600 for r in runs
             if isinstance(r.get("characterization_s"), (int, float))]
    temp = [r.get("temperature_change_c") for r in runs
            if isinstance(r.get("temperature_change_c"), (int, float))]
    if hours and temp:
        out += ["", f"The plan's characterization takes {statistics.median(hours):.2f} h of simulated "
                f"time and the temperature changes by {statistics.median(temp):+.2f} °C (median)."]
    return out + [""]


def readme_block(main, kinder):
    """The README's headline table: the same figures as the main and kinder
    sections, in their format (`--check-quotes` relies on it)."""
    runs = [s for s in (main, kinder) if s is not None]
    head = "| mode | paper-faithful stage (default) |" + (" kinder stage |" if kinder else "") + " paper |"
    out = [head, "|---|---|" + ("---|" if kinder else "") + "---|"]

    def pair(s, *path):
        return f"{um(get(s, *path, 'square', 'ap_um'))} / {um(get(s, *path, 'random', 'ap_um'))}"

    def by_mode(s, mode):
        return f"{um(get(s, 'square', mode, 'ap_um'))} / {um(get(s, 'random', mode, 'ap_um'))}"
    g = get(main, "grid") or {}
    rows = [("raw", lambda s: by_mode(s, "raw"), "22 / 22"),
            ("the paper's procedure (lookup tables, live drift off)",
             lambda s: pair(s, "drift", "compare", "off"), "3.5 / 7"),
            ("lookup tables, live drift adaptive", lambda s: by_mode(s, "table"), "–"),
            ("model table", lambda s: by_mode(s, "model"), "–"),
            ("closed loop", lambda s: by_mode(s, "closed_loop"), "–"),
            ("sweep tables (on the fly), live drift off", lambda s: pair(s, "sweep", "run-sweep"), "–"),
            (f"2-D grid map ({num(g.get('pitch_um'), 0)} µm pitch, {g.get('nodes', '–')} nodes), "
             "live drift off", lambda s: pair(s, "grid"), "–")]
    for label, f, paper in rows:
        out.append(f"| {label} | " + " | ".join(f(s) for s in runs) + f" | {paper} |")
    return out


NUMBER = re.compile(r"\d+\.\d+")


def check_quotes(readme, md):
    """Every decimal figure of the README's generated block occurs in the
    results file: the README quotes only what that file holds."""
    with open(readme, encoding="utf-8") as f:
        block = re.search(re.escape(BEGIN.format("readme")) + r"\n(.*?)" + re.escape(END.format("readme")),
                          f.read(), re.S)
    with open(md, encoding="utf-8") as f:
        held = set(NUMBER.findall(f.read()))
    if not block:
        print(f"results: {readme} has no generated block ({BEGIN.format('readme')})", file=sys.stderr)
        return 1
    missing = sorted(set(NUMBER.findall(block.group(1))) - held)
    if missing:
        print(f"results: {readme} quotes figures that {md} does not hold: {', '.join(missing)}; "
              "regenerate both with scripts/results.py (see the head of docs/results.md)",
              file=sys.stderr)
        return 1
    print(f"results: every figure {readme} quotes is in {md}")
    return 0


def placeholder(name):
    return [f'<a id="{name}"></a>', "", f"## {TITLES[name]}", "",
            f"Not generated yet. Make it with `{COMMANDS[name]}` and "
            f"`scripts/results.py --{name} FILE.json…` (the commands at the head of this file).", ""]


def wrap(name, lines):
    body = "\n".join(lines).rstrip("\n")
    return f"{BEGIN.format(name)}\n{body}\n{END.format(name)}"


def sections_of(text):
    out = {}
    for name in ORDER:
        m = re.search(re.escape(BEGIN.format(name)) + r"\n.*?\n" + re.escape(END.format(name)),
                      text, re.S)
        if m:
            out[name] = m.group(0)
    return out


HEADER = """# Results

Every measured figure the project quotes, each section generated by
`scripts/results.py` from the JSON of the run it names: do not edit by
hand. The README and the design notes link here. The runs are on the
simulated rig's virtual clock, so a seed gives the same JSON on any
machine; only wall time (where shown) is the machine's.

To regenerate (a release or test-profile build of `hil-sim`; the full job
takes a few minutes of wall time per run):

```sh
hil-sim run --json --seed 1 --out /tmp/r-main >/dev/null
hil-sim run --json --seed 1 --model config/stage-model.toml --out /tmp/r-kinder >/dev/null
for n in 1 2 3 4 5; do hil-sim run --json --seed $n --out /tmp/r-seed$n >/dev/null; done
hil-sim run --short --json --seed 1 >/tmp/r-short.json
micropos paper --seeds 5 --json --model config/stage-model.toml >/tmp/r-paper-default.json  # exit 3: it misses statements
micropos paper --seeds 5 --json --model config/stage-model-paper.toml >/tmp/r-paper-faithful.json
python3 scripts/results.py --main /tmp/r-main/data/run.json --kinder /tmp/r-kinder/data/run.json \\
  --seeds /tmp/r-seed?/data/run.json --short /tmp/r-short.json \\
  --paper-default /tmp/r-paper-default.json --paper-faithful /tmp/r-paper-faithful.json
```

The `short` section is checked at every run of the test command
(`scripts/results.py --check-short`, from `scripts/test.sh`): a change that
moves the short job's JSON fails until this file is regenerated.
"""


def short_text(path):
    s, _, digest = load(path)
    return wrap("short", run_section("short", s, None, digest, None))


def check_short(json_path, md_path):
    with open(md_path, encoding="utf-8") as f:
        have = sections_of(f.read()).get("short")
    want = short_text(json_path)
    if have == want:
        print(f"results: the short section of {md_path} is what {json_path} gives")
        return 0
    print(f"results: the short section of {md_path} is stale: it is not what a fresh "
          f"`{COMMANDS['short']}` gives. Regenerate it:\n"
          f"  hil-sim run --short --json --seed 1 > short.json && "
          f"python3 scripts/results.py --short short.json", file=sys.stderr)
    diff = difflib.unified_diff((have or "").splitlines(), want.splitlines(),
                                f"{md_path} (short)", "fresh run", lineterm="", n=1)
    for line in list(diff)[:60]:
        print(line, file=sys.stderr)
    return 1


def git_commit():
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], check=True,
                              capture_output=True, text=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--main")
    ap.add_argument("--kinder")
    ap.add_argument("--seeds", nargs="+")
    ap.add_argument("--short")
    ap.add_argument("--paper-default")
    ap.add_argument("--paper-faithful")
    ap.add_argument("--commit")
    ap.add_argument("--out", default="docs/results.md")
    ap.add_argument("--readme", default="README.md",
                    help="the README whose headline table is written with --main")
    ap.add_argument("--check-short", nargs="+", metavar=("JSON", "MD"))
    ap.add_argument("--check-quotes", nargs=2, metavar=("README", "MD"))
    a = ap.parse_args()
    if a.check_quotes:
        return check_quotes(*a.check_quotes)
    if a.check_short:
        if len(a.check_short) > 2:
            ap.error("--check-short takes JSON and, optionally, the results file")
        md = a.check_short[1] if len(a.check_short) == 2 else "docs/results.md"
        return check_short(a.check_short[0], md)
    if bool(a.paper_default) != bool(a.paper_faithful):
        ap.error("--paper-default and --paper-faithful go together")
    if not (a.main or a.kinder or a.seeds or a.short or a.paper_default):
        ap.error("give at least one run (--main, --kinder, --seeds, --paper-…, --short)")
    commit = a.commit or git_commit()
    old = {}
    if os.path.exists(a.out):
        with open(a.out, encoding="utf-8") as f:
            old = sections_of(f.read())
    new = {}
    loaded = {}
    for name in ["main", "kinder"]:
        path = getattr(a, name)
        if path:
            s, wall, digest = load(path)
            loaded[name] = s
            new[name] = wrap(name, run_section(name, s, wall, digest, commit))
    if "main" in loaded and a.readme:
        with open(a.readme, encoding="utf-8") as f:
            text = f.read()
        pat = re.compile(re.escape(BEGIN.format("readme")) + r".*?" + re.escape(END.format("readme")), re.S)
        if not pat.search(text):
            ap.error(f"{a.readme} has no {BEGIN.format('readme')} … {END.format('readme')} block")
        block = wrap("readme", readme_block(loaded["main"], loaded.get("kinder")))
        with open(a.readme, "w", encoding="utf-8") as f:
            f.write(pat.sub(lambda _: block, text, count=1))
    if a.seeds:
        runs = [load(p)[::2] for p in a.seeds]
        new["seeds"] = wrap("seeds", seeds_section(runs, commit))
    if a.paper_default:
        with open(a.paper_default, encoding="utf-8") as f:
            d = json.load(f)
        with open(a.paper_faithful, encoding="utf-8") as f:
            p = json.load(f)
        new["paper"] = wrap("paper", paper_section(d, p, commit))
    if a.short:
        new["short"] = short_text(a.short)
    parts = [HEADER]
    for name in ORDER:
        parts.append(new.get(name) or old.get(name) or wrap(name, placeholder(name)))
    with open(a.out, "w", encoding="utf-8") as f:
        f.write("\n\n".join(p.rstrip("\n") for p in parts) + "\n")
    print(f"results: wrote {a.out} ({', '.join(sorted(new))} regenerated)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
