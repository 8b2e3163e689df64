"""The client's side of the protocol, without a daemon: exception classes
against the daemon's source of truth, request encoding."""

import math
import pathlib
import pickle
import re

import pytest

import micropos
from micropos import _protocol as proto
from micropos.errors import ERROR_CLASSES, MicroposError, error_from_reply

REPO = pathlib.Path(__file__).resolve().parents[3]


def rust_error_codes():
    """(variant, wire code) pairs from src/daemon/protocol/error.rs."""
    text = (REPO / "src" / "daemon" / "protocol" / "error.rs").read_text()
    pairs = re.findall(r'ErrorCode::(\w+) => "(\w+)"', text)
    assert len(pairs) >= 20, "error.rs changed shape; update this parser"
    return pairs


def test_every_protocol_error_code_has_its_class():
    pairs = rust_error_codes()
    assert {code for _, code in pairs} == set(ERROR_CLASSES)
    for variant, code in pairs:
        cls = ERROR_CLASSES[code]
        assert cls.__name__ == variant, f"{code} should be class {variant}"
        assert issubclass(cls, MicroposError)
        assert cls.code == code
        assert getattr(micropos, variant) is cls, f"micropos.{variant} not exported"


def test_documented_codes_match_the_source():
    doc = (REPO / "docs" / "socket-protocol.md").read_text()
    section = doc.split("### Error codes (stable)", 1)[1].split("## Commands", 1)[0]
    # Backticked words of the section; config keys contain a dot, codes do not.
    documented = set(re.findall(r"`([a-z_]+)`", section))
    assert documented <= set(ERROR_CLASSES)
    assert set(ERROR_CLASSES) <= documented


def test_error_reply_becomes_its_class_with_code_and_message():
    reply = {"id": 3, "ok": False, "error": {"code": "out_of_travel", "message": "axis x ..."}}
    e = error_from_reply(reply)
    assert type(e) is micropos.OutOfTravel
    assert (e.code, e.message, e.reply) == ("out_of_travel", "axis x ...", reply)
    assert str(e) == "out_of_travel: axis x ..."


def test_unknown_code_still_raises_with_its_code():
    e = error_from_reply({"ok": False, "error": {"code": "brand_new", "message": "m"}})
    assert type(e) is MicroposError and e.code == "brand_new"


def test_errors_survive_pickling():
    e = error_from_reply({"ok": False, "error": {"code": "busy", "message": "job"}})
    back = pickle.loads(pickle.dumps(e))
    assert type(back) is micropos.Busy and back.code == "busy" and back.reply == e.reply
    j = micropos.JobFailed("x", job={"state": "failed", "error": "camera_stalled"})
    back = pickle.loads(pickle.dumps(j))
    assert back.job == j.job and back.state == "failed"


def test_client_side_errors_are_builtin_kinds_too():
    assert issubclass(micropos.ConnectionLost, ConnectionError)
    assert issubclass(micropos.DaemonUnreachable, micropos.ConnectionLost)
    assert issubclass(micropos.Timeout, TimeoutError)
    assert issubclass(micropos.JobCancelled, micropos.JobFailed)


def test_encode_drops_unset_fields_and_refuses_nan():
    req = proto.move(1.5, None, "raw", False, True, None)
    assert req == {"cmd": "move", "x_um": 1.5, "mode": "raw", "relative": False, "wait": True}
    assert proto.encode(req).endswith(b"\n") and b"\n" not in proto.encode(req)[:-1]
    with pytest.raises(micropos.BadValue, match="x_um"):
        proto.encode(proto.move(math.nan, 1.0, "raw", False, True, None))
    with pytest.raises(micropos.BadValue, match="drift_reference_um"):
        proto.encode(proto.characterize_start(
            log=None, axes=None, step_um=None, x_range_um=None, y_range_um=None, cycles=None,
            frames_per_point=None, settle_s=None, drift_every_s=None,
            drift_reference_um=[0.0, math.inf]))


def test_a_bare_string_is_one_topic_not_letters():
    assert proto.subscribe("job") == {"cmd": "subscribe", "topics": ["job"]}
    assert proto.subscribe(None) == {"cmd": "subscribe"}


def test_unreachable_daemon_raises_at_once(tmp_path):
    with pytest.raises(micropos.DaemonUnreachable, match="cannot connect"):
        micropos.Rig(str(tmp_path / "nothing.sock"), timeout=2)


def test_timeouts_must_be_positive():
    with pytest.raises(ValueError):
        micropos.AsyncRig("/nonexistent", timeout=0)


def parse_rs_fields():
    """Command → accepted fields, from the daemon's request schema
    (docs/socket-schema.json, generated from src/daemon/protocol/schema.rs,
    the list the parser refuses unknown fields by)."""
    import json
    schema = json.loads((REPO / "docs" / "socket-schema.json").read_text())
    fields = {}
    for cmd, c in schema["commands"].items():
        if "actions" in c:
            fields[cmd] = {"action"}.union(*(a["fields"] for a in c["actions"].values()))
        else:
            fields[cmd] = set(c["fields"])
    assert {"move", "characterize", "validate", "tables", "drift", "figures"} <= set(fields)
    return fields


def keys(req):
    return set(req) - {"cmd"}


def test_requests_use_exactly_the_daemons_field_names():
    known = parse_rs_fields()
    assert keys(proto.move(1.0, 2.0, "raw", True, True, 0.5, "tip")) == known["move"]
    assert keys(proto.reference("x")) == known["reference"]
    assert keys(proto.subscribe(["job"])) == known["subscribe"]
    assert keys(proto.characterize_start(
        log="a.csv", axes="xy", step_um=5.0, x_range_um=1.0, y_range_um=1.0, cycles=1,
        frames_per_point=1, settle_s=0.1, drift_every_s=0.0, drift_reference_um=[0.0, 0.0],
        mode="sweep", velocity_um_per_s=120.0, uncorrected_log="u.csv", moves_per_cycle=3,
        anchor_spacing_um=250.0, unanchored_log="n.csv", plan="grid", pitch_um=100.0,
        approach="both", order="serpentine",
    )) == known["characterize"]
    assert keys(proto.validate_start(
        test="both", modes=["raw"], cycles=1, log="v.csv", origin_x_um=0.0, origin_y_um=0.0,
        square_step_um=500.0, table="t.toml", model_table="m.toml", frames_per_point=1,
        settle_s=0.1,
    )) == known["validate"]
    tables = keys(proto.tables_build("c.csv", "stem", ["paper"], True)) | keys(
        proto.tables_activate("t.toml"))
    assert tables == known["tables"]
    assert keys(proto.drift_set("static", 1.0, 10.0)) == known["drift"]
    assert keys(proto.figures("validate", "v.csv")) == known["figures"]
    assert proto.figures("characterize", None) == {"cmd": "figures", "job": "characterize"}
    for cmd in ("status", "position", "stop", "config", "version"):
        assert known[cmd] == set()


def public_methods(cls):
    import inspect
    return {n: inspect.signature(f) for n, f in inspect.getmembers(cls, inspect.isfunction)
            if not n.startswith("_")}


@pytest.mark.parametrize("sync_cls, async_cls", [
    (micropos.Rig, micropos.AsyncRig),
    (micropos.Job, micropos.AsyncJob),
    (micropos.Tables, micropos.aio.AsyncTables),
    (micropos.Drift, micropos.aio.AsyncDrift),
])
def test_the_asyncio_api_mirrors_the_blocking_one(sync_cls, async_cls):
    import inspect
    sync, aio = public_methods(sync_cls), public_methods(async_cls)
    assert set(sync) <= set(aio)
    for name, sig in sync.items():
        assert list(sig.parameters) == list(aio[name].parameters), name
        assert inspect.iscoroutinefunction(getattr(async_cls, name)), name


def test_a_daemon_of_another_protocol_version_is_refused(tmp_path):
    """The one case the real daemon cannot produce: a stand-in answers
    ``version`` with protocol 2, and the client refuses to go on."""
    import json
    import socket
    import threading

    path = str(tmp_path / "v2.sock")
    server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    server.bind(path)
    server.listen(1)

    def answer():
        conn, _ = server.accept()
        with conn:
            req = json.loads(conn.makefile().readline())
            conn.sendall(json.dumps({"id": req["id"], "ok": True, "protocol": 2}).encode() + b"\n")

    t = threading.Thread(target=answer)
    t.start()
    try:
        with pytest.raises(micropos.ProtocolError, match="protocol 2"):
            micropos.Rig(path, timeout=5)
    finally:
        t.join(5)
        server.close()
