#!/usr/bin/env python3
"""Standstill plateaus of a flexure-stage step test, as a micropos measurement log.

Input: the capacitive sensor's raw recordings of the open-souce-SWLI flexure stage
(CSV: acquisition time, epoch ms, Distance1 µm, ...; 520.83 Hz), one file per run of
the Arduino step program (N steps out, N steps back, a dwell after each step).
Output (stdout): a measurement log (format micropos-measurement-log/1), one record per
standstill plateau.

The rule (the same for every run, only the nominal step and the dwell change):
* a sample is at rest when |x(t + 19 ms) - x(t - 19 ms)| < thr, with
  thr = max(0.1 step, min(0.08 um, 0.3 step), 10 sensor noise) (the noise: 1.4826 x
  the median |successive difference| / sqrt 2); a plateau is >= 100 ms at rest;
* its value is the mean over the 140 ms ending 10 ms before the plateau ends, or, for
  a plateau longer than the dwell + 150 ms (a run's first and last rest), before the
  dwell after its start ends (the first rest: before the first move);
* moves between plateaus: round(dt / the median dt between plateaus) (the program
  moves once per dwell + pulse train; a missed plateau counts two), outward before
  the turning point (the plateau farthest from the final rest), back after it; the
  index is counted back from the run's last plateau (the final rest, 0);
* +x = increasing sensor reading; approach = the sign of the index change into the
  plateau; a run's first plateau is `rest` (segment `start`) when it is a long rest
  (the recording starts before the program's first move), else the direction of the
  motion whose dwell it interrupts (the next change's sign);
* target = command = index x nominal step (open loop); meas = reading - the final
  rest reading of the first run given; t_s = mean epoch time of the window, s from
  the first record.

Usage: swli_plateaus.py [-m KEY=VALUE ...] STEP_UM DWELL_MS RUN1.csv [RUN2.csv ...] > log.csv
(runs are cycles 1, 2, ...; each -m adds a metadata line). Standard library only.
"""
import statistics
import sys


def read(path):
    t, x = [], []
    with open(path, encoding="latin-1") as fh:
        for line in fh:
            if line.startswith("#"):
                continue
            f = line.split(",")
            if len(f) < 3:
                continue
            t.append(float(f[1]) / 1000.0)
            x.append(float(f[2]))
    return t, x


def plateaus(t, x, step, dwell_s):
    n = len(t)
    dt = (t[-1] - t[0]) / (n - 1)
    h = max(1, round(0.019 / dt))
    # Sample noise from successive differences (robust: the recording is
    # at rest most of the time, moves are rare large differences).
    noise = 1.4826 * statistics.median(abs(b - a) for a, b in zip(x, x[1:])) / 2**0.5
    thr = max(0.1 * step, min(0.08, 0.3 * step), 10.0 * noise)
    rest = [False] * n
    for i in range(h, n - h):
        rest[i] = abs(x[i + h] - x[i - h]) < thr
    # Samples within h of the ends count as at rest when their neighbours are.
    for i in range(h):
        rest[i] = rest[h]
        rest[n - 1 - i] = rest[n - 1 - h]
    out = []
    i = 0
    while i < n:
        if not rest[i]:
            i += 1
            continue
        j = i
        while j < n and rest[j]:
            j += 1
        start, end = t[i], t[j - 1]
        if end - start >= 0.1:
            long = end - start > dwell_s + 0.15
            first = i == 0
            stop = end - 0.01
            if long and not first:
                stop = min(stop, start + dwell_s - 0.01)
            w = [k for k in range(i, j) if stop - 0.14 <= t[k] <= stop]
            if w:
                out.append(
                    {
                        "t": sum(t[k] for k in w) / len(w),
                        "x": sum(x[k] for k in w) / len(w),
                        "at_start": first and long,
                    }
                )
        i = j
    return out, thr, noise


def main():
    args = sys.argv[1:]
    meta = []
    while len(args) >= 2 and args[0] == "-m":
        meta.append(args[1].split("=", 1))
        args = args[2:]
    if len(args) < 3 or any(len(m) != 2 for m in meta):
        sys.exit(__doc__)
    step = float(args[0])
    dwell_s = float(args[1]) / 1000.0
    runs = []
    for path in args[2:]:
        t, x = read(path)
        p, thr, noise = plateaus(t, x, step, dwell_s)
        runs.append((path, p, thr, noise))
    zero = runs[0][1][-1]["x"]
    t0 = runs[0][1][0]["t"]
    print("# format: micropos-measurement-log/1")
    for k, v in meta:
        print(f"# {k.strip()}: {v.strip()}")
    for c, (path, p, thr, noise) in enumerate(runs, start=1):
        print(
            f"# run_{c}: {path.split('/')[-1]}: {len(p)} plateaus, rest threshold {thr:.4f} um, "
            f"sensor noise {noise:.4f} um"
        )
    print("t_s,segment,cycle,x_target_um,y_target_um,x_cmd_um,y_cmd_um,x_meas_um,y_meas_um,approach")
    for c, (path, p, thr, noise) in enumerate(runs, start=1):
        # Moves between plateaus from their timing (the program moves once
        # per period: the dwell plus the pulse train), directions from the
        # turning point (the plateau farthest from the final rest): out
        # before it, back after it. Neither needs the step to be resolved,
        # so a step below the sensor's rest threshold still counts.
        dts = [b["t"] - a["t"] for a, b in zip(p, p[1:])]
        period = statistics.median(dts) if dts else 1.0
        counts = [max(1, round(d / period)) for d in dts]
        turn = max(range(len(p)), key=lambda k: abs(p[k]["x"] - p[-1]["x"]))
        out_sign = 1 if p[turn]["x"] >= p[-1]["x"] else -1
        moves = [c * (out_sign if k < turn else -out_sign) for k, c in enumerate(counts)]
        idx = [0] * len(p)
        for k in range(len(p) - 2, -1, -1):
            idx[k] = idx[k + 1] - moves[k]
        for k, q in enumerate(p):
            if k == 0:
                if q["at_start"]:
                    seg, app = "start", "rest"
                else:
                    nxt = next((m for m in moves if m != 0), 1)
                    seg, app = "scan_x", "fwd" if nxt > 0 else "bwd"
            else:
                seg = "scan_x"
                m = moves[k - 1]
                app = "fwd" if m > 0 else ("bwd" if m < 0 else "rest")
            target = idx[k] * step
            print(
                f"{q['t'] - t0:.6f},{seg},{c},{target:.4f},0.0000,{target:.4f},0.0000,"
                f"{q['x'] - zero:.4f},0.0000,{app}"
            )


if __name__ == "__main__":
    main()
