"""Fixtures: the real ``hil-sim serve`` and the real ``microposd``, no mocks.

A simulated rig is ``hil-sim serve --link-dir DIR`` (two C-863 controllers on
ptys, the camera on a socket, a simulated clock) plus ``microposd`` with
config/microposd-sim.toml moved into DIR, exactly as the README starts them.
One referenced rig is shared by the tests that leave it usable
(``shared_rig``); tests that need an unreferenced rig, or that kill, freeze or
stop the daemon, get their own (``fresh_rig``).

Binaries: ``MICROPOSD_BIN`` and ``HIL_SIM_BIN``, else ``$CARGO_TARGET_DIR``
(default ``target/``) ``/debug/``; build them with
``cargo build -p micropos -p hil-sim --bins`` (scripts/pyclient.sh does).

Timing: the machine may be loaded (2 cores, parallel builds), so waits are on
conditions with generous deadlines, never bare sleeps.
"""

import os
import pathlib
import re
import select
import shutil
import signal
import subprocess
import tempfile
import time
from typing import Any, Dict, Iterator, Optional

import pytest

import micropos

REPO = pathlib.Path(__file__).resolve().parents[3]
#: Simulated seconds per wall second: a reference run (~15 s simulated) takes
#: about a second, a long move still lasts long enough to be stopped.
TIME_SCALE = 20.0
#: Generous: builds may run in parallel on 2 cores.
DEADLINE_S = 60.0


def _binary(env: str, name: str) -> pathlib.Path:
    path = os.environ.get(env)
    if path:
        return pathlib.Path(path)
    target = os.environ.get("CARGO_TARGET_DIR")
    base = pathlib.Path(target) if target else REPO / "target"
    return base / "debug" / name


def daemon_config(link_dir: pathlib.Path) -> pathlib.Path:
    """config/microposd-sim.toml moved into ``link_dir``, with test timings:
    generous controller timeouts for a loaded machine, a camera stall detected
    after 10 s (a debug-build frame render on a loaded 2-core machine has
    taken more than 3 s), one job retry. Compensated moves and validations
    outside a table's small test area are warned, not refused (the tests
    drive the client's plumbing with 1 mm tables; the refusal has its own
    test in hil-sim/tests/it/comp_range.rs). No vision tie after each
    reference (about 6 s of wall time each here; no test of the client
    needs it, and the tie has its own test in tests/it/daemon_process.rs)."""
    text = (REPO / "config" / "microposd-sim.toml").read_text()
    text = text.replace("/tmp/rig", str(link_dir))
    text = re.sub(r"(?m)^poll_interval_ms = \d+", "poll_interval_ms = 50", text)
    text = re.sub(r"(?m)^timeout_ms = \d+", "timeout_ms = 2000", text)
    text = re.sub(r"(?m)^job_retries = \d+", "job_retries = 1", text)
    text = re.sub(r"(?m)^\[camera\]$", "[camera]\ntimeout_ms = 10000", text)
    text = re.sub(r"(?m)^tie_after_reference = true", "tie_after_reference = false", text)
    text += '\n[compensation]\noutside_table = "warn"\n'
    path = link_dir / "microposd.toml"
    path.write_text(text)
    return path


def _stop_process(proc: "subprocess.Popen[Any]", grace_s: float = 10.0) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=grace_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


class SimRig:
    """``hil-sim serve`` and ``microposd`` in a temporary directory."""

    def __init__(self) -> None:
        # Short path: a Unix socket path must fit in 108 bytes.
        self.dir = pathlib.Path(tempfile.mkdtemp(prefix="mp-py-", dir="/tmp"))
        self.socket = str(self.dir / "micropos.sock")
        self.sim: Optional["subprocess.Popen[str]"] = None
        self.daemon: Optional["subprocess.Popen[bytes]"] = None
        self.control_path = ""
        self._start_sim()
        self.start_daemon()

    def _start_sim(self) -> None:
        binary = _binary("HIL_SIM_BIN", "hil-sim")
        if not binary.exists():
            pytest.fail(f"hil-sim not found at {binary}: "
                        "cargo build -p hil-sim --bins (or set HIL_SIM_BIN)")
        self.sim = subprocess.Popen(
            [str(binary), "serve", "--link-dir", str(self.dir), "--seed", "1",
             "--time-scale", str(TIME_SCALE)],
            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        assert self.sim.stdout is not None
        ready, _, _ = select.select([self.sim.stdout], [], [], DEADLINE_S)
        assert ready, "hil-sim printed no ready line"
        line = self.sim.stdout.readline().strip()
        assert line.startswith("hil-sim ready "), line
        fields = dict(item.split("=", 1) for item in line.split()[2:] if "=" in item)
        self.control_path = fields["control"]

    def start_daemon(self) -> None:
        """Starts microposd and waits until both controllers are connected."""
        binary = _binary("MICROPOSD_BIN", "microposd")
        if not binary.exists():
            pytest.fail(f"microposd not found at {binary}: "
                        "cargo build -p micropos --bins (or set MICROPOSD_BIN)")
        cfg = daemon_config(self.dir)
        log = open(self.dir / "microposd.log", "ab")
        self.daemon = subprocess.Popen([str(binary), "-c", str(cfg)],
                                       stdout=subprocess.DEVNULL, stderr=log)
        log.close()
        deadline = time.monotonic() + DEADLINE_S
        while True:
            assert self.daemon.poll() is None, f"microposd exited: {self.daemon_log()}"
            try:
                with micropos.Rig(self.socket, timeout=10) as rig:
                    rig_state = rig.status()["rig"]
                    if rig_state["connected"] == {"x": True, "y": True}:
                        return
            except micropos.ConnectionLost:
                pass
            assert time.monotonic() < deadline, "microposd did not come up"
            time.sleep(0.05)

    def freeze_daemon(self) -> None:
        """SIGSTOP, and wait until every thread of the daemon is stopped
        (delivery is asynchronous: a thread running on another core could
        still answer a request sent right after the kill)."""
        assert self.daemon is not None
        self.daemon.send_signal(signal.SIGSTOP)
        tasks = pathlib.Path(f"/proc/{self.daemon.pid}/task")
        deadline = time.monotonic() + DEADLINE_S
        while True:
            states = []
            for t in tasks.iterdir():
                try:
                    # The state follows the parenthesized command name.
                    states.append((t / "stat").read_text().rsplit(")", 1)[1].split()[0])
                except (OSError, IndexError):
                    pass
            if states and all(st in ("T", "t") for st in states):
                return
            assert time.monotonic() < deadline, f"microposd not stopped: {states}"
            time.sleep(0.01)

    def thaw_daemon(self) -> None:
        """SIGCONT after :meth:`freeze_daemon`."""
        assert self.daemon is not None
        self.daemon.send_signal(signal.SIGCONT)

    def daemon_log(self) -> str:
        try:
            return (self.dir / "microposd.log").read_text()[-4000:]
        except OSError:
            return ""

    def control(self, **req: Any) -> Dict[str, Any]:
        """One request to hil-sim's control socket (faults, ground truth)."""
        import json
        import socket

        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
            s.settimeout(DEADLINE_S)
            s.connect(self.control_path)
            s.sendall(json.dumps(req).encode() + b"\n")
            buf = b""
            while not buf.endswith(b"\n"):
                chunk = s.recv(65536)
                assert chunk, "control socket closed"
                buf += chunk
        reply: Dict[str, Any] = json.loads(buf)
        assert reply.get("ok") is True, f"{req} -> {reply}"
        return reply

    def data_dir(self) -> pathlib.Path:
        return self.dir / "data"

    def close(self) -> None:
        for proc in (self.daemon, self.sim):
            if proc is not None:
                _stop_process(proc)
        shutil.rmtree(self.dir, ignore_errors=True)


@pytest.fixture(scope="session")
def shared_rig() -> Iterator[SimRig]:
    """One simulated rig for the whole session, referenced."""
    sim = SimRig()
    try:
        with micropos.Rig(sim.socket) as rig:
            rig.reference()
        yield sim
    finally:
        sim.close()


@pytest.fixture
def fresh_rig() -> Iterator[SimRig]:
    """A simulated rig of its own, unreferenced, for destructive tests."""
    sim = SimRig()
    try:
        yield sim
    finally:
        sim.close()


@pytest.fixture
def rig(shared_rig: SimRig) -> Iterator[micropos.Rig]:
    """A client of the shared rig; the rig is idle, uncompensated and
    referenced when the test starts."""
    with micropos.Rig(shared_rig.socket, timeout=20, long_timeout=120) as r:
        _idle(r)
        yield r


def _idle(r: micropos.Rig) -> None:
    """Ends what an earlier test may have left running."""
    job = r.status().get("job")
    if job and job.get("state") == "running":
        r.stop()
    deadline = time.monotonic() + DEADLINE_S
    while r.status()["rig"]["activity"] != "idle":
        assert time.monotonic() < deadline, r.status()
        time.sleep(0.05)
    if r.status()["rig"]["mode"] == "fault":
        r.reset()
    if r.status()["rig"]["mode"] != "idle":
        r.reference()
    r.tables.activate(None)
