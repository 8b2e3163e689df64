"""Error paths that need a rig of their own: unreferenced axes, lost lines,
and a daemon that is killed, frozen or shut down. The rule under test: a call
raises within its timeout, it never hangs."""

import asyncio
import signal
import threading
import time

import pytest

import micropos


def test_unreferenced_rig_refuses_moves_and_jobs(fresh_rig):
    with micropos.Rig(fresh_rig.socket, timeout=20, long_timeout=120) as rig:
        assert rig.status()["rig"]["mode"] == "unreferenced"
        with pytest.raises(micropos.NotReferenced, match="reference"):
            rig.move(100, 100, mode="raw")
        # The daemon accepts the job and the job fails at its first move.
        job = rig.characterize(step_um=500, x_range_um=1000, y_range_um=1000, cycles=1)
        with pytest.raises(micropos.JobFailed) as e:
            job.wait(timeout=60, poll_s=0.1)
        assert (e.value.state, e.value.error_code) == ("failed", "not_referenced")
        assert type(e.value) is micropos.JobFailed
        rig.reference("x")
        rig.move(x_um=100, mode="raw")
        with pytest.raises(micropos.NotReferenced, match="axis y"):
            rig.move(100, 100, mode="raw")
        rig.reference("y")
        assert rig.move(100, 100, mode="raw")["on_target"] is True


def test_a_dropped_controller_line_is_not_connected_then_latched_until_reset(fresh_rig):
    with micropos.Rig(fresh_rig.socket, timeout=20, long_timeout=120) as rig:
        rig.reference()
        with rig.subscribe(["fault"], timeout=30) as faults:
            fresh_rig.control(axis="x", fault="drop_line")
            deadline = time.monotonic() + 30
            while rig.status()["rig"]["connected"]["x"]:
                assert time.monotonic() < deadline
                time.sleep(0.05)
            with pytest.raises(micropos.NotConnected, match="axis x"):
                rig.move(200, 200, mode="raw")
            ev = faults.next(timeout=30)
            assert ev["event"] in ("fault", "state", "stopped", "garbled"), ev
        fresh_rig.control(axis="x", fault="restore_line")
        while not rig.status()["rig"]["connected"]["x"]:
            assert time.monotonic() < deadline + 30
            time.sleep(0.05)
        # The line loss stays latched until a client resets it.
        with pytest.raises(micropos.FaultLatched, match="axis x line down"):
            rig.move(200, 200, mode="raw")
        assert rig.status()["rig"]["mode"] == "fault"

        async def reset():
            async with micropos.AsyncRig(fresh_rig.socket, timeout=20) as arig:
                return await arig.reset()

        cleared = asyncio.run(reset())["cleared"]
        assert "axis x line down" in cleared["reason"]
        assert rig.reset()["cleared"] is None
        assert rig.move(200, 200, mode="raw")["on_target"] is True


def test_killed_daemon_raises_connection_lost_mid_move_and_the_rig_reconnects(fresh_rig):
    rig = micropos.Rig(fresh_rig.socket, timeout=5, long_timeout=60)
    rig.reference()
    rig.move(100, 100, mode="raw")
    # The kill must come while the move runs: 14.8 mm take ~0.5 s of wall
    # time at the test time scale, and the kill follows the first position
    # change within milliseconds.
    outcome = {}

    def far_move():
        t0 = time.monotonic()
        try:
            rig.move(14900, 14900, mode="raw")
        except micropos.MicroposError as e:
            outcome["error"] = e
        outcome["took_s"] = time.monotonic() - t0

    t = threading.Thread(target=far_move)
    t.start()
    deadline = time.monotonic() + 30
    with micropos.Rig(fresh_rig.socket, timeout=10) as watcher:
        while watcher.position()["controller"]["x_um"] < 200:
            assert time.monotonic() < deadline, "the move did not start"
    fresh_rig.daemon.kill()
    fresh_rig.daemon.wait()
    t.join(10)
    assert not t.is_alive(), "the move hung on a dead daemon"
    assert isinstance(outcome.get("error"), micropos.ConnectionLost), outcome
    assert outcome["took_s"] < 10

    # Nobody listens any more: every call raises at once, nothing hangs.
    t0 = time.monotonic()
    with pytest.raises(micropos.DaemonUnreachable):
        rig.status()
    assert time.monotonic() - t0 < 5

    # The daemon comes back (systemd restarts it): the same Rig reconnects.
    fresh_rig.start_daemon()
    assert rig.status()["rig"]["connected"] == {"x": True, "y": True}
    rig.close()


def test_killed_daemon_ends_a_subscription_with_connection_lost(fresh_rig):
    with micropos.Rig(fresh_rig.socket, timeout=5) as rig:
        events = rig.subscribe(["fault"])
        fresh_rig.daemon.kill()
        fresh_rig.daemon.wait()
        t0 = time.monotonic()
        with pytest.raises(micropos.ConnectionLost):
            events.next(timeout=30)
        assert time.monotonic() - t0 < 5
        assert next(events, None) is None


def test_frozen_daemon_times_out_calls_and_subscriptions(fresh_rig):
    rig = micropos.Rig(fresh_rig.socket, timeout=1.5, long_timeout=3)
    events = rig.subscribe(["fault"], keepalive_s=0.5)
    fresh_rig.freeze_daemon()
    try:
        t0 = time.monotonic()
        with pytest.raises(micropos.Timeout, match="within 1.5 s"):
            rig.status()
        assert time.monotonic() - t0 < 5
        t0 = time.monotonic()
        with pytest.raises(micropos.Timeout, match="keepalive"):
            # What the daemon sent before it froze (a fault event on a
            # loaded machine) may still be queued; a frozen daemon sends
            # nothing more, so the keepalive then runs out.
            while True:
                events.next()
        assert time.monotonic() - t0 < 5
    finally:
        fresh_rig.thaw_daemon()
    # Thawed: the next call reconnects and gets its own answer, not a late
    # reply meant for the call that timed out.
    assert rig.version()["protocol"] == 1
    assert rig.status()["ok"] is True
    rig.close()


def test_daemon_shutdown_is_reported_to_subscribers(fresh_rig):
    with micropos.Rig(fresh_rig.socket, timeout=5) as rig:
        events = rig.subscribe(["fault"])
        fresh_rig.daemon.send_signal(signal.SIGTERM)
        # The daemon halts both axes first (a `halted` event; fault events
        # of the connecting rig may come before it), then says it
        # is shutting down: usually its shutting_down line; when the process
        # exits before its connection task writes it, the socket just closes.
        with pytest.raises((micropos.ShuttingDown, micropos.ConnectionLost)):
            while True:
                ev = events.next(timeout=30)
                assert "event" in ev, ev
        fresh_rig.daemon.wait(timeout=30)
        with pytest.raises(micropos.ConnectionLost):
            rig.status()
