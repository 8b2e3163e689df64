"""The blocking client against the real microposd and hil-sim (shared rig)."""

import json
import socket
import threading
import time

import pytest

import micropos
from micropos.errors import error_from_reply

# A characterization that takes seconds: 500 µm steps over 1000 µm, 1 cycle.
SMALL_SCAN = dict(step_um=500.0, x_range_um=1000.0, y_range_um=1000.0, cycles=1,
                  frames_per_point=1, settle_s=0.1)


def test_version_status_position(rig):
    v = rig.version()
    assert v["protocol"] == 1 and "move" in v["commands"]
    assert rig.daemon_version["protocol"] == 1
    st = rig.status()
    assert st["rig"]["referenced"] == {"x": True, "y": True}
    assert st["limits"]["x_um"] == [0.0, 15000.0]
    assert "config" in rig.config()
    pos = rig.position()
    assert set(pos) >= {"commanded", "controller", "vision"}


def test_one_rig_serves_several_threads(rig):
    errors = []

    def worker():
        try:
            for _ in range(20):
                assert rig.status()["ok"] is True
                assert "controller" in rig.position()
        except Exception as e:  # reported below, with the thread's error
            errors.append(e)

    threads = [threading.Thread(target=worker) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert not errors


def test_raw_move_waits_on_target_and_position_agrees(rig):
    r = rig.move(2000, 12000, mode="raw")
    assert r["on_target"] is True
    assert r["commanded"] == {"x_um": 2000.0, "y_um": 12000.0}
    assert r["reported"] == pytest.approx({"x_um": 2000.0, "y_um": 12000.0}, abs=0.01)
    pos = rig.position()
    assert pos["controller"]["x_um"] == pytest.approx(2000.0, abs=0.01)
    assert pos["controller"]["y_um"] == pytest.approx(12000.0, abs=0.01)


def test_relative_and_single_axis_moves(rig):
    rig.move(5000, 5000, mode="raw")
    r = rig.move(x_um=250, mode="raw", relative=True)
    assert r["commanded"]["x_um"] == 5250.0
    r = rig.move(y_um=4000, mode="raw")
    assert r["commanded"]["y_um"] == 4000.0
    assert rig.position()["commanded"] == {"x_um": 5250.0, "y_um": 4000.0}


def test_move_without_wait_returns_before_on_target(rig):
    rig.move(1000, 1000, mode="raw")
    r = rig.move(14000, 14000, mode="raw", wait=False)
    assert r["ok"] is True
    deadline = time.monotonic() + 30
    while rig.position()["controller"]["x_um"] != pytest.approx(14000.0, abs=0.01):
        assert time.monotonic() < deadline
        time.sleep(0.05)


def test_reference_one_axis(rig):
    r = rig.reference("x")
    assert r["reported"]["x_um"] == pytest.approx(7500.0, abs=0.01)
    assert rig.status()["rig"]["referenced"] == {"x": True, "y": True}


def test_characterize_job_tables_build_and_compensated_move(rig, shared_rig):
    with rig.subscribe(["job"], timeout=60) as events:
        # With drift references (every 5 s of rig time), so that the table
        # records a drift baseline and live drift can be measured below.
        job = rig.characterize("py-char.csv", drift_every_s=5, **SMALL_SCAN)
        assert (job.kind, job.log) == ("characterize", "py-char.csv")
        assert job.started["job"]["state"] == "running"
        total = job.started["job"]["total"]
        assert total == 12

        # While it runs: the rig is busy for everything that moves.
        p = job.progress
        assert p["kind"] == "characterize" and p["total"] == total
        with pytest.raises(micropos.Busy):
            rig.move(100, 100, mode="raw")
        with pytest.raises(micropos.Busy):
            rig.reference()
        with pytest.raises(micropos.Busy):
            rig.characterize("py-other.csv", **SMALL_SCAN)

        final = job.wait(timeout=150, poll_s=0.2)
        assert final["job"]["state"] == "done"
        assert final["job"]["done"] == total
        assert job.progress["state"] == "done"
        assert rig.characterize_status()["job"] == final["job"]

        # The job's events arrived, in order, ending with done.
        seen = []
        while not seen or seen[-1].get("state") == "running":
            seen.append(events.next(timeout=30))
        assert all(e["event"] == "job" for e in seen)
        dones = [e["done"] for e in seen]
        assert dones == sorted(dones) and dones[-1] == total

    log = shared_rig.data_dir() / "py-char.csv"
    assert log.exists()

    # The paper's figures of that log, as data: Figs. 4 and 5 (one cycle:
    # no repeatability figure, and a note says why) and a summary per axis.
    figs = rig.figures(log="py-char.csv")
    assert figs["job"] == "characterize" and figs["log"] == "py-char.csv"
    assert len(figs["figures"]) >= 2
    assert {a["axis"] for a in figs["axes"]} == {"x", "y"}
    assert all(a["points"] > 0 for a in figs["axes"])

    # Nothing to resume any more; cancelling a finished job changes nothing.
    job.cancel()
    assert job.progress["state"] == "done"
    with pytest.raises(micropos.JobState):
        rig.characterize_resume("py-char.csv")

    built = rig.tables.build("py-char.csv", name="py", activate=True)
    assert built["written"] == ["py-paper.toml", "py-model.toml"]
    assert built["active"] == "py-paper.toml"
    listing = rig.tables.list()
    assert {"py-paper.toml", "py-model.toml"} <= set(listing["files"])
    assert listing["active"] == "py-paper.toml"

    r = rig.move(3000, 3000)  # compensated by default
    assert r["mode"] == "compensated" and r["on_target"] is True
    assert r["target"] == {"x_um": 3000.0, "y_um": 3000.0}

    # Live drift against the active table's baseline: measured now.
    measured = rig.drift.measure()
    assert "measured" in measured and measured["drift"]["references"] >= 1
    rig.drift.reset()

    # Deactivate, load and activate again by name; the model table too.
    assert rig.tables.activate(None)["active"] is None
    with pytest.raises(micropos.NoActiveTable):
        rig.move(3000, 3000)
    rig.tables.load("py-model.toml")
    assert rig.tables.activate("py-model.toml")["active"] == "py-model.toml"
    assert rig.move(3100, 3100)["on_target"] is True

    # Closed loop with a stalled camera, then undecodable frames.
    shared_rig.control(camera="stall")
    try:
        with pytest.raises(micropos.CameraStalled):
            rig.move(3200, 3200, mode="closed_loop")
        frames = rig.status()["camera"]["frames"]
        shared_rig.control(camera="garbage")
        # A grab sent while the camera stalled holds the daemon's camera
        # until its own timeout (as a hung camera would): the move below is
        # only about undecodable frames once the daemon has seen one.
        _wait_until(lambda: rig.status()["camera"]["frames"] > frames, 30.0)
        with pytest.raises(micropos.LowQuality):
            rig.move(3300, 3300, mode="closed_loop")
    finally:
        shared_rig.control(camera="normal")
    r = rig.move(3400, 3400, mode="closed_loop", tolerance_um=0.5)
    assert r["ok"] is True


def _wait_until(cond, timeout_s: float) -> None:
    """Polls ``cond`` every 0.1 s until it holds; fails after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < deadline, "condition not met in time"
        time.sleep(0.1)


@pytest.fixture
def paper_table(rig):
    """A lookup table of the shared rig: the one the characterization test
    built, or a new one when that test did not run."""
    if "py-paper.toml" not in rig.tables.list()["files"]:
        rig.characterize("py-char.csv", **SMALL_SCAN).wait(timeout=150, poll_s=0.2)
        rig.tables.build("py-char.csv", name="py", kinds=["paper"])
    rig.tables.load("py-paper.toml")
    return "py-paper.toml"


def test_validate_job_with_results_and_cancel(rig, paper_table):
    job = rig.validate("square", modes=["raw", "table"], cycles=1, square_step_um=4000,
                       origin_x_um=1000, origin_y_um=1000, table=paper_table,
                       log="py-val.csv", frames_per_point=1, settle_s=0.1)
    assert job.kind == "validate" and job.log == "py-val.csv"
    final = job.wait(timeout=150, poll_s=0.2)
    assert rig.validate_status()["validation"] == final["validation"]
    square = final["validation"]["results"]["square"]
    assert set(square) == {"raw", "table"}
    assert square["table"]["ap_um"] < square["raw"]["ap_um"]
    # The figures of the log agree with the job's own results.
    figs = rig.figures("validate", log="py-val.csv")
    ap = {(r["test"], r["mode"]): r["ap_max_um"] for r in figs["results"]}
    for mode in ("raw", "table"):
        assert ap[("square", mode)] == pytest.approx(square[mode]["ap_um"], abs=1e-3)

    job = rig.validate("random", modes=["raw"], cycles=3, origin_x_um=1000, origin_y_um=1000,
                       log="py-val-cancel.csv", settle_s=0.1)
    job.cancel()
    with pytest.raises(micropos.JobCancelled) as e:
        job.wait(timeout=60, poll_s=0.2)
    assert e.value.state == "cancelled"
    with pytest.raises(micropos.JobState):
        rig.validate_cancel()


def test_cancelled_characterization_resumes(rig):
    job = rig.characterize("py-resume.csv", **{**SMALL_SCAN, "axes": "x"})
    total = job.started["job"]["total"]
    deadline = time.monotonic() + 60
    while job.progress["done"] < 2:
        assert time.monotonic() < deadline
        time.sleep(0.1)
    rig.characterize_cancel()
    with pytest.raises(micropos.JobCancelled):
        job.wait(timeout=60, poll_s=0.2)
    resumed = rig.characterize_resume("py-resume.csv")
    assert resumed.log == "py-resume.csv"
    assert rig.current_job().log == "py-resume.csv"
    assert resumed.wait(timeout=150, poll_s=0.2)["job"]["done"] == total


def test_characterization_with_moves_of_varied_length(rig):
    # `moves_per_cycle` adds that many direct moves per cycle after the
    # scans (the log's `moves` segment), each one point of the job.
    plain = 12  # SMALL_SCAN's scan points, as asserted above
    job = rig.characterize("py-moves.csv", moves_per_cycle=3, **SMALL_SCAN)
    assert job.started["job"]["total"] == plain + 3
    final = job.wait(timeout=150, poll_s=0.2)
    assert final["job"]["done"] == plain + 3
    with pytest.raises(micropos.BadValue):
        rig.characterize("py-moves-bad.csv", moves_per_cycle=-1, **SMALL_SCAN)


def test_stop_halts_a_move_waited_on_in_another_thread(rig):
    # A race against the stage: on a loaded machine the move may end before
    # the stop is sent; then it is tried again.
    for _attempt in range(3):
        rig.move(500, 500, mode="raw")
        outcome = {}

        def far_move():
            try:
                outcome["reply"] = rig.move(14500, 14500, mode="raw")
            except micropos.MicroposError as e:
                outcome["error"] = e

        t = threading.Thread(target=far_move)
        t.start()
        deadline = time.monotonic() + 30
        with micropos.Rig(rig.socket_path, timeout=10) as watcher:
            while watcher.position()["controller"]["x_um"] < 600:
                assert time.monotonic() < deadline, "the move did not start"
        assert rig.stop()["stopped"] is True
        t.join(30)
        assert not t.is_alive()
        if "reply" not in outcome:
            break
    assert isinstance(outcome.get("error"), micropos.Halted), outcome
    assert rig.position()["controller"]["x_um"] < 14000


def test_drift_show_set_reset_measure(rig):
    d = rig.drift.show()["drift"]
    assert d["method"] in ("off", "static", "adaptive")
    d = rig.drift.set("adaptive", every_s=120, time_constant_s=600)["drift"]
    assert (d["method"], d["every_s"], d["time_constant_s"]) == ("adaptive", 120, 600)
    d = rig.drift.set(every_s=60)["drift"]
    assert (d["method"], d["every_s"]) == ("adaptive", 60), "unset fields stay"
    assert rig.drift.reset()["drift"]["references"] == 0
    with pytest.raises(micropos.NoActiveTable):
        rig.drift.measure()
    rig.drift.set("off")


@pytest.mark.parametrize("call, exc", [
    (lambda r: r.move(16000, 100, mode="raw"), micropos.OutOfTravel),
    (lambda r: r.move(-1, 100, mode="raw"), micropos.OutOfTravel),
    (lambda r: r.move(100, 100), micropos.NoActiveTable),
    (lambda r: r.move(mode="raw"), micropos.MissingField),
    (lambda r: r.move(100, 100, mode="sideways"), micropos.BadValue),
    (lambda r: r.move("100", 100, mode="raw"), micropos.WrongType),
    (lambda r: r.move(float("nan"), 100, mode="raw"), micropos.BadValue),
    (lambda r: r.move(100, 100, mode="closed_loop", tolerance_um=-1), micropos.BadValue),
    (lambda r: r.reference("z"), micropos.BadValue),
    (lambda r: r.subscribe(["everything"]), micropos.BadValue),
    (lambda r: r.characterize(step_um=-5), micropos.BadValue),
    (lambda r: r.characterize(cycles=0), micropos.BadValue),
    (lambda r: r.characterize("../escape.csv"), micropos.BadValue),
    (lambda r: r.characterize(drift_reference_um=[1.0]), micropos.WrongType),
    (lambda r: r.characterize_resume("no-such-log.csv"), micropos.LogError),
    (lambda r: r.validate("circle"), micropos.BadValue),
    (lambda r: r.validate(modes=[]), micropos.BadValue),
    (lambda r: r.validate(modes=["raw"], square_step_um=0.5), micropos.BadValue),
    (lambda r: r.tables.load("no-such-table.toml"), micropos.BadValue),
    (lambda r: r.tables.activate("no-such-table.toml"), micropos.BadValue),
    (lambda r: r.tables.load("../../etc/passwd"), micropos.BadValue),
    (lambda r: r.tables.build("no-such-log.csv"), micropos.LogError),
    (lambda r: r.figures(log="no-such-log.csv"), micropos.LogError),
    (lambda r: r.figures("diagnose"), micropos.BadValue),
    (lambda r: r.figures(log="../escape.csv"), micropos.BadValue),
    (lambda r: r.tables.build("x.csv", kinds=["lookup"]), micropos.BadValue),
    (lambda r: r.drift.set("sometimes"), micropos.BadValue),
    (lambda r: r.drift.set(every_s=0), micropos.BadValue),
    (lambda r: r.request("teleport"), micropos.UnknownCommand),
    (lambda r: r.request("status", verbose=True), micropos.BadValue),
    (lambda r: r.request("tables", action="load"), micropos.MissingField),
    (lambda r: r.request("tables", action="load", name="a" * 70000), micropos.RequestTooLarge),
])
def test_refusals_raise_their_class_and_the_connection_stays_usable(rig, call, exc):
    with pytest.raises(exc) as e:
        call(rig)
    assert type(e.value) is exc
    assert e.value.message and e.value.code == exc.code
    assert rig.status()["ok"] is True


def test_unknown_table_is_named_in_the_message(rig):
    with pytest.raises(micropos.BadValue) as e:
        rig.tables.load("no-such-table.toml")
    assert "no-such-table.toml" in e.value.message


@pytest.mark.parametrize("line, cls", [
    (b"this is not json\n", micropos.BadJson),
    (b"[1, 2]\n", micropos.NotAnObject),
    (b'{"id": 1}\n', micropos.MissingField),
])
def test_malformed_lines_get_codes_that_map_to_classes(shared_rig, line, cls):
    """Lines the typed API cannot produce: the daemon's answers to them still
    map to the right classes."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.settimeout(20)
        s.connect(shared_rig.socket)
        s.sendall(line)
        buf = b""
        while not buf.endswith(b"\n"):
            chunk = s.recv(65536)
            assert chunk
            buf += chunk
    assert type(error_from_reply(json.loads(buf))) is cls


def test_position_events_stream(rig):
    with rig.subscribe(["position"], timeout=20) as events:
        assert events.topics == ["position"]
        rig.move(6000, 6000, mode="raw")
        sources = set()
        for ev in events:
            assert ev["event"] in ("position", "lagged")
            sources.add(ev.get("source"))
            if {"controller", "vision"} <= sources:
                break
    assert next(events, None) is None, "a closed subscription ends"
