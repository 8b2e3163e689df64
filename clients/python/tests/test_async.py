"""The asyncio client against the real microposd and hil-sim.

Plain ``asyncio.run`` in each test: no pytest plugin needed."""

import asyncio
import time

import pytest

import micropos
from micropos import AsyncRig


def run(coro):
    return asyncio.run(coro)


def test_async_queries_moves_and_errors(shared_rig):
    async def main():
        async with AsyncRig(shared_rig.socket, timeout=20, long_timeout=120) as rig:
            assert rig.daemon_version["protocol"] == 1
            await rig.tables.activate(None)
            st = await rig.status()
            assert st["rig"]["referenced"] == {"x": True, "y": True}
            r = await rig.move(4000, 9000, mode="raw")
            assert r["on_target"] is True
            pos = await rig.position()
            assert pos["controller"]["x_um"] == pytest.approx(4000.0, abs=0.01)
            assert (await rig.reference("y"))["reported"]["y_um"] == pytest.approx(7500, abs=0.01)
            with pytest.raises(micropos.OutOfTravel):
                await rig.move(100, 15001, mode="raw")
            with pytest.raises(micropos.NoActiveTable):
                await rig.move(100, 100)
            with pytest.raises(micropos.BadValue):
                await rig.move(100, 100, mode="sideways")
            with pytest.raises(micropos.UnknownCommand):
                await rig.request("teleport")
            with pytest.raises(micropos.JobState):
                await rig.validate_cancel()
            with pytest.raises(micropos.BadValue):
                await rig.drift.set("sometimes")
            assert (await rig.drift.show())["drift"]["method"] in ("off", "static", "adaptive")
            assert "files" in await rig.tables.list()
            # Concurrent calls on one rig are serialized, each gets its reply.
            replies = await asyncio.gather(rig.status(), rig.position(), rig.version())
            assert "rig" in replies[0] and "controller" in replies[1] and "protocol" in replies[2]

    run(main())


def test_async_job_handle_events_and_tables(shared_rig):
    async def main():
        rig = await AsyncRig.connect(shared_rig.socket, timeout=20, long_timeout=120)
        try:
            events = await rig.subscribe(["job"], timeout=60)
            async with events:
                job = await rig.characterize(
                    "py-async.csv", step_um=500.0, x_range_um=1000.0, y_range_um=1000.0,
                    cycles=1, frames_per_point=1, settle_s=0.1)
                assert job.log == "py-async.csv"
                p = await job.progress
                assert p["kind"] == "characterize" and p["total"] == job.started["job"]["total"]
                with pytest.raises(micropos.Busy):
                    await rig.move(100, 100, mode="raw")
                final = await job.wait(timeout=150, poll_s=0.2)
                assert final["job"]["state"] == "done"
                last = None
                async for ev in events:
                    last = ev
                    if ev.get("state") != "running":
                        break
                assert last is not None and last["state"] == "done"
            figs = await rig.figures(log="py-async.csv")
            assert figs["log"] == "py-async.csv" and figs["figures"]
            built = await rig.tables.build("py-async.csv", kinds=["paper"], activate=True)
            assert built["active"] == "py-async-paper.toml"
            r = await rig.move(2500, 2500)
            assert r["mode"] == "compensated"
            await rig.tables.activate(None)
        finally:
            await rig.close()

    run(main())


def test_async_stop_halts_a_waited_move(shared_rig):
    async def main():
        async with AsyncRig(shared_rig.socket, timeout=20, long_timeout=120) as rig:
            # A race against the stage: tried again if the move ended first.
            for _attempt in range(3):
                await rig.move(500, 500, mode="raw")
                move = asyncio.ensure_future(rig.move(14500, 14500, mode="raw"))
                async with AsyncRig(shared_rig.socket) as watcher:
                    deadline = time.monotonic() + 30
                    while (await watcher.position())["controller"]["x_um"] < 600:
                        assert time.monotonic() < deadline
                    assert (await watcher.stop())["stopped"] is True
                try:
                    await move
                except micropos.Halted:
                    break
            else:
                pytest.fail("every move ended before its stop")

    run(main())


def test_async_cancelled_call_does_not_desync_the_connection(shared_rig):
    async def main():
        async with AsyncRig(shared_rig.socket, timeout=20, long_timeout=120) as rig:
            await rig.move(500, 500, mode="raw")
            task = asyncio.ensure_future(rig.move(9000, 9000, mode="raw"))
            await asyncio.sleep(0.05)
            task.cancel()
            with pytest.raises(asyncio.CancelledError):
                await task
            # The next call gets its own reply, not the cancelled move's.
            assert "protocol" in await rig.version()
            await rig.stop()

    run(main())


def test_async_connection_lost_and_timeout(fresh_rig):
    async def main():
        rig = await AsyncRig.connect(fresh_rig.socket, timeout=1.5, long_timeout=3)
        events = await rig.subscribe(["fault"], keepalive_s=0.5)
        fresh_rig.freeze_daemon()
        try:
            t0 = time.monotonic()
            with pytest.raises(micropos.Timeout):
                await rig.status()
            with pytest.raises(micropos.Timeout, match="keepalive"):
                await events.next()
            assert time.monotonic() - t0 < 8
        finally:
            fresh_rig.thaw_daemon()
        assert (await rig.status())["ok"] is True

        events = await rig.subscribe(["fault"])
        fresh_rig.daemon.kill()
        fresh_rig.daemon.wait()
        t0 = time.monotonic()
        with pytest.raises(micropos.ConnectionLost):
            await events.next(timeout=30)
        with pytest.raises(micropos.ConnectionLost):
            await rig.status()
        assert time.monotonic() - t0 < 5
        with pytest.raises(StopAsyncIteration):
            await events.__anext__()
        await rig.close()

    run(main())
