"""PI's own Python client (PIPython) driving the simulated C-863 over its pty.

PIPython is what PI ships to its customers; if it cannot drive the simulator
through its pure-Python serial path, the simulator does not behave like a
C-863. Each test starts a fresh `hil-sim serve` (fresh controllers), talks to
the X controller through `PISerial`, and checks real values: positions
within tolerance, error codes via `GCSError.val`.

Run: see README.md in this directory.
"""

import os
import pathlib
import select
import signal
import subprocess
import time

import pytest
from pipython import GCSDevice, GCSError, pitools
from pipython.pidevice.gcs2.gcs2device import GCS2Device
from pipython.pidevice.interfaces.piserial import PISerial

REPO = pathlib.Path(__file__).resolve().parents[2]
# Simulated seconds per wall second: referencing (up to ~15 s simulated)
# takes well under a second, moves stay slow enough to be caught mid-way.
TIME_SCALE = 20
POS_TOL_MM = 1e-6
AXIS = "1"


def hil_sim_binary():
    env = os.environ.get("HIL_SIM_BIN")
    if env:
        return pathlib.Path(env)
    target = os.environ.get("CARGO_TARGET_DIR")
    base = pathlib.Path(target) if target else REPO / "target"
    return base / "debug" / "hil-sim"


@pytest.fixture
def sim(tmp_path):
    """A running `hil-sim serve`; yields the dict of links {'x': .., 'y': ..}."""
    binary = hil_sim_binary()
    if not binary.exists():
        pytest.fail(f"hil-sim binary not found at {binary} (build it or set HIL_SIM_BIN)")
    proc = subprocess.Popen(
        [str(binary), "serve", "--link-dir", str(tmp_path),
         "--time-scale", str(TIME_SCALE), "--seed", "1"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        ready, _, _ = select.select([proc.stdout], [], [], 20)
        assert ready, "hil-sim printed no ready line within 20 s"
        line = proc.stdout.readline().strip()
        assert line.startswith("hil-sim ready "), f"unexpected first line {line!r}"
        links = dict(item.split("=", 1) for item in line.split()[2:])
        assert {"x", "y"} <= set(links), f"no x=, y= links in {line!r}"
        yield links
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            rc = proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            pytest.fail("hil-sim did not exit within 10 s of SIGTERM")
    assert rc == 0, f"hil-sim exited with {rc}: {proc.stderr.read()}"
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists(), "links left behind"


@pytest.fixture
def dev(sim):
    """A GCSDevice on the X controller through PIPython's pure-Python serial path."""
    gateway = PISerial(sim["x"], 115200)
    # The context manager matters: PIPython keeps connection callbacks at
    # class level, and only leaving the context unregisters this device's.
    with GCSDevice(gateway=gateway) as device:
        yield device


@pytest.fixture
def ready_dev(dev):
    """The X controller after PIPython's own startup: servo on, referenced."""
    pitools.startup(dev, refmodes=["FRF"])
    return dev


def pos(dev):
    return dev.qPOS(AXIS)[AXIS]


def test_qidn_identifies_a_c863(dev):
    idn = dev.qIDN()
    assert idn.startswith("(c)2015 Physik Instrumente (PI) GmbH & Co. KG, C-863.11, ")
    assert idn.endswith(", 01.110\n")
    serial = idn.split(",")[2].strip()
    assert len(serial) == 10 and serial.isdigit()
    assert dev.devname == "C-863.11"
    # CSV? 2.0 made PIPython pick its GCS 2 command set.
    assert isinstance(dev.gcsdevice, GCS2Device)
    assert dev.qCSV() == 2.0
    assert dev.qSAI() == [AXIS]
    assert dev.qSAI_ALL() == [AXIS]


def test_startup_references_with_frf(dev):
    assert dev.qFRF(AXIS)[AXIS] is False
    assert dev.qSVO(AXIS)[AXIS] is False
    assert pos(dev) == 0.0
    pitools.startup(dev, refmodes=["FRF"])
    assert dev.qFRF(AXIS)[AXIS] is True
    assert dev.qSVO(AXIS)[AXIS] is True
    assert dev.qRON(AXIS)[AXIS] is True
    # The M-111.1DG reference switch is at mid travel, 7.5 mm.
    assert pos(dev) == pytest.approx(7.5, abs=POS_TOL_MM)
    assert dev.qERR() == 0


def test_mov_waitontarget_qpos(ready_dev):
    dev = ready_dev
    dev.MOV(AXIS, 3.25)
    assert dev.qMOV(AXIS)[AXIS] == pytest.approx(3.25, abs=POS_TOL_MM)
    pitools.waitontarget(dev, AXIS, timeout=30)
    assert dev.qONT(AXIS)[AXIS] is True
    assert pos(dev) == pytest.approx(3.25, abs=POS_TOL_MM)
    dev.MOV({AXIS: 12.0000125})
    pitools.waitontarget(dev, timeout=30)
    assert pos(dev) == pytest.approx(12.0000125, abs=POS_TOL_MM)


def test_mvr_moves_relative_to_target(ready_dev):
    dev = ready_dev
    dev.MVR(AXIS, -1.5)
    pitools.waitontarget(dev, AXIS, timeout=30)
    assert pos(dev) == pytest.approx(6.0, abs=POS_TOL_MM)
    dev.MVR(AXIS, 0.25)
    pitools.waitontarget(dev, AXIS, timeout=30)
    assert pos(dev) == pytest.approx(6.25, abs=POS_TOL_MM)
    # MVR is checked against the soft limits too.
    with pytest.raises(GCSError) as err:
        dev.MVR(AXIS, 10.0)
    assert err.value.val == 7
    assert pos(dev) == pytest.approx(6.25, abs=POS_TOL_MM)


def test_vel_and_qvel(ready_dev):
    dev = ready_dev
    assert dev.qVEL(AXIS)[AXIS] == pytest.approx(1.0)
    dev.VEL(AXIS, 0.1)
    assert dev.qVEL(AXIS)[AXIS] == pytest.approx(0.1)
    # 2 mm at 0.1 mm/s: 20 s simulated, 1 s wall. A quarter in, the axis is
    # between start and target (wide margins: CI machines stall).
    dev.MOV(AXIS, 9.5)
    time.sleep(5.0 / TIME_SCALE)
    p = pos(dev)
    assert 7.6 < p < 9.4, p
    pitools.waitontarget(dev, AXIS, timeout=30)
    assert pos(dev) == pytest.approx(9.5, abs=POS_TOL_MM)
    # Above the stage's maximum velocity (parameter 0xA, 1.5 mm/s): error 8.
    with pytest.raises(GCSError) as err:
        dev.VEL(AXIS, 2.0)
    assert err.value.val == 8
    assert dev.qVEL(AXIS)[AXIS] == pytest.approx(0.1)


def test_is_moving(ready_dev):
    dev = ready_dev
    assert dev.IsMoving(AXIS)[AXIS] is False
    dev.VEL(AXIS, 0.25)
    dev.MOV(AXIS, 11.0)  # 14 s simulated, 0.7 s wall
    assert dev.IsMoving(AXIS)[AXIS] is True
    assert dev.IsMoving()[AXIS] is True
    pitools.waitontarget(dev, AXIS, timeout=30)
    assert dev.IsMoving(AXIS)[AXIS] is False
    assert pos(dev) == pytest.approx(11.0, abs=POS_TOL_MM)


def test_hlt_stops_smoothly_with_error_10(ready_dev):
    dev = ready_dev
    dev.VEL(AXIS, 0.2)
    dev.MOV(AXIS, 14.5)
    time.sleep(2.0 / TIME_SCALE)
    assert dev.IsMoving(AXIS)[AXIS] is True
    with pytest.raises(GCSError) as err:
        dev.HLT(AXIS)
    assert err.value.val == 10
    # HLT decelerates: wait for rest, then the axis holds where it stopped.
    deadline = time.time() + 10
    while dev.IsMoving(AXIS)[AXIS]:
        assert time.time() < deadline
        time.sleep(0.01)
    stopped = pos(dev)
    assert 7.5 < stopped < 14.5
    time.sleep(1.0 / TIME_SCALE)
    assert pos(dev) == stopped
    assert dev.qMOV(AXIS)[AXIS] == pytest.approx(stopped, abs=POS_TOL_MM)
    assert dev.qERR() == 0
    # noraise masks exactly error 10.
    dev.HLT(AXIS, noraise=True)
    assert dev.qERR() == 0


def test_mov_beyond_tmx_is_error_7(ready_dev):
    dev = ready_dev
    tmx = dev.qTMX(AXIS)[AXIS]
    tmn = dev.qTMN(AXIS)[AXIS]
    assert (tmn, tmx) == (0.0, 15.0)
    assert pitools.getmaxtravelrange(dev, AXIS)[AXIS] == tmx
    with pytest.raises(GCSError) as err:
        dev.MOV(AXIS, tmx + 0.001)
    assert err.value.val == 7
    assert dev.IsMoving(AXIS)[AXIS] is False
    assert dev.qMOV(AXIS)[AXIS] == pytest.approx(7.5, abs=POS_TOL_MM)
    assert pos(dev) == pytest.approx(7.5, abs=POS_TOL_MM)
    with pytest.raises(GCSError) as err:
        dev.MOV(AXIS, tmn - 0.001)
    assert err.value.val == 7
    # Exactly on the limit is allowed.
    dev.MOV(AXIS, tmx)
    pitools.waitontarget(dev, AXIS, timeout=60)
    assert pos(dev) == pytest.approx(tmx, abs=POS_TOL_MM)


def test_moves_before_referencing_are_error_5(dev):
    with pytest.raises(GCSError) as err:
        dev.MOV(AXIS, 1.0)
    assert err.value.val == 5


def test_unknown_command_sets_error_2(dev):
    dev.errcheck = False
    dev.send("FOO 1")
    assert dev.qERR() == 2
    assert dev.qERR() == 0
    dev.errcheck = True
    with pytest.raises(GCSError) as err:
        dev.send("BAR")
    assert err.value.val == 2
    # The first error sticks until read.
    dev.errcheck = False
    dev.send("FOO")
    dev.send("MOV 2 1")
    assert dev.qERR() == 2
    dev.send("MOV 2 1")
    assert dev.qERR() == 15


def test_is_controller_ready_during_referencing(ready_dev):
    dev = ready_dev
    assert dev.IsControllerReady() is True
    dev.MOV(AXIS, 2.0)
    pitools.waitontarget(dev, AXIS, timeout=30)
    # 5.5 mm back to the switch at 0.25 mm/s (parameter 0x50) plus the
    # edge search: ~23.5 s simulated, ~1.2 s wall. Meanwhile #7 says busy.
    dev.SPA(AXIS, 0x50, 0.25)
    dev.FRF(AXIS)
    assert dev.IsControllerReady() is False
    assert dev.qFRF(AXIS)[AXIS] is False
    pitools.waitonreferencing(dev, AXIS, timeout=30)
    assert dev.IsControllerReady() is True
    assert dev.qFRF(AXIS)[AXIS] is True
    assert pos(dev) == pytest.approx(7.5, abs=POS_TOL_MM)


def test_stopall(ready_dev):
    dev = ready_dev
    dev.VEL(AXIS, 0.2)
    dev.MOV(AXIS, 1.0)
    time.sleep(2.0 / TIME_SCALE)
    assert dev.IsMoving(AXIS)[AXIS] is True
    pitools.stopall(dev)
    assert dev.IsMoving(AXIS)[AXIS] is False
    stopped = pos(dev)
    assert 1.0 < stopped < 7.5
    time.sleep(1.0 / TIME_SCALE)
    assert pos(dev) == stopped
    # stopall masked the error 10 of #24; nothing is left pending.
    assert dev.qERR() == 0
    # Unmasked, #24 reports error 10.
    with pytest.raises(GCSError) as err:
        dev.StopAll()
    assert err.value.val == 10


def test_help_and_parameters(dev):
    hlp = dev.qHLP()
    for cmd in ("MOV", "POS?", "FRF", "#7", "#24"):
        assert f"\n{cmd} " in hlp
    assert "0x3C=" in dev.qHPA()
    # PIPython learns parameter types from HPA? and converts SPA? values.
    assert dev.qSPA(AXIS, 0x3C)[AXIS][0x3C] == "M-111.1DG"
    assert dev.qSPA(AXIS, 0x15)[AXIS][0x15] == 15.0
    assert dev.qSPA(AXIS, 0xE)[AXIS][0xE] == 145000
    assert dev.qCST(AXIS)[AXIS] == "M-111.1DG"
    # A query the controller refuses is not answered (like a C-863): the
    # client times out, and ERR? says why.
    dev.errcheck = False
    dev.gcscommands._msgs.timeout = 300
    with pytest.raises(GCSError) as err:
        dev.qSPA(AXIS, 0x999)
    assert err.value.val == -7  # PIPython's COM_TIMEOUT
    dev.gcscommands._msgs.timeout = 7000
    assert dev.qERR() == 54


def test_data_recorder_through_qdrr(ready_dev):
    """PIPython's data recorder calls (TNR?, DRC, RTR, DRT, DRL?, DRR?) on
    the simulated recorder: the actual position every 20 servo cycles
    (1 ms) from the move that triggers it, read back as GCS array data."""
    dev = ready_dev
    assert dev.qTNR() == 2
    dev.DRC(1, AXIS, 2)  # table 1: actual position of axis 1
    dev.RTR(20)
    assert dev.qRTR() == 20
    dev.VEL(AXIS, 0.5)
    dev.DRT(1, 1)  # start at the next position-changing command
    dev.MOV(AXIS, 8.5)
    pitools.waitontarget(dev, AXIS, timeout=30)
    # 2 s of motion at 0.5 mm/s: the 1024-point table is full.
    n = dev.qDRL(1)[1]
    assert n == 1024
    header = dev.qDRR(1, 1, n)
    deadline = time.time() + 20
    while dev.bufstate is not True:
        assert time.time() < deadline, "qDRR data not read within 20 s"
        time.sleep(0.05)
    data = dev.bufdata
    assert float(header["SAMPLE_TIME"]) == pytest.approx(0.001)
    assert int(header["NDATA"]) == n
    assert len(data) == 1 and len(data[0]) == n
    values = data[0]
    assert values[0] == pytest.approx(7.5, abs=1e-4)
    assert all(b >= a for a, b in zip(values, values[1:]))
    # 1.023 s after the start: past the acceleration, below the target.
    assert 7.7 < values[-1] < 8.5
    assert dev.qERR() == 0
