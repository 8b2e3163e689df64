#!/usr/bin/env python3
"""Reference the stage, characterize it, build the paper's tables, and move
compensated: the daemon's whole workflow from a script.

Against the simulated rig (see the top-level README):

    mkdir -p /tmp/rig
    hil-sim serve --link-dir /tmp/rig --time-scale 5 &
    microposd -c config/microposd-sim.toml &
    python3 clients/python/examples/characterize_and_compensate.py /tmp/rig/micropos.sock
"""

import sys

import micropos


def main(socket_path: str) -> int:
    with micropos.Rig(socket_path) as rig:
        print("referencing…")
        rig.reference()
        rig.move(x_um=2000, y_um=2000, mode="raw")  # no table yet: raw

        # Subscribe first: events of a job started before would be missed.
        with rig.subscribe(["job"]) as events:
            # A small characterization (the paper used 5 µm steps and 3 cycles).
            job = rig.characterize("example.csv", step_um=100, x_range_um=1000,
                                   y_range_um=500, cycles=1)
            for event in events:
                if event["event"] != "job":
                    continue
                print(f"\r{event['done']}/{event['total']} points", end="", flush=True)
                if event["state"] != "running":
                    break
        print()
        try:
            job.wait()  # raises JobFailed / JobCancelled unless it completed
        except micropos.JobFailed as e:
            print(f"characterization {e.state}: {e.job.get('error')}; "
                  f"resume with rig.characterize_resume({job.log!r})")
            return 1

        built = rig.tables.build(job.log, activate=True)
        print("tables:", ", ".join(built["written"]), "→ active:", built["active"])

        try:
            reply = rig.move(x_um=2500, y_um=2300)  # compensated, waits on target
        except micropos.OutOfTravel as e:
            print("target refused:", e.message)
            return 1
        print("compensated move: commanded", reply["commanded"], "for target", reply["target"])
        print("vision says", rig.position()["vision"])
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else micropos.DEFAULT_SOCKET))
