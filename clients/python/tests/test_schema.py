"""The client's requests against the daemon's request schema, without a daemon.

``docs/socket-schema.json`` is generated from the Rust protocol types
(``src/daemon/protocol/schema.rs``; a Rust test fails when it is stale). Here
every public method of the sync and asyncio clients is called, once with
every optional argument set and once with the defaults, on a fake connection
that records the request lines; each request must name a command, action and
fields the schema lists, with values of the schema's types, and every
command, action and field of the schema must be sent by some method (or be
listed below as a deliberate exception). The keyword types of
``micropos.types`` must hold the schema's words.
"""

import asyncio
import inspect
import json
import math
import pathlib
import typing
from typing import Any, Dict, List, Optional, Set, Tuple

import pytest

import micropos
from micropos import _protocol as proto
from micropos import aio, client, types

REPO = pathlib.Path(__file__).resolve().parents[3]
SCHEMA = json.loads((REPO / "docs" / "socket-schema.json").read_text())

#: Methods that send no request of their own shape: ``request`` passes any
#: command through (for commands newer than the client), ``close`` sends
#: nothing.
NOT_BUILDERS = {"request", "close", "connect"}

#: Schema entries no method sends, each with the reason. Empty means the
#: client reaches every command, action and field of the protocol.
UNREACHED: Dict[Tuple[str, str, str], str] = {}

#: The ``micropos.types`` keyword aliases and the schema field whose words
#: they must be.
WORD_TYPES = {
    "MoveMode": ("move", "", "mode"),
    "Axes": ("reference", "", "axes"),
    "Topic": ("subscribe", "", "topics"),
    "ValidateTest": ("validate", "start", "test"),
    "ValidateMode": ("validate", "start", "modes"),
    "TableKind": ("tables", "build", "kinds"),
    "DriftMethod": ("drift", "set", "method"),
    "JobKind": ("figures", "", "job"),
    "CharacterizeMode": ("characterize", "start", "mode"),
    "CharacterizePlan": ("characterize", "start", "plan"),
    "GridApproach": ("characterize", "start", "approach"),
    "GridOrder": ("characterize", "start", "order"),
}


def schema_fields(cmd: str, action: str) -> Dict[str, Any]:
    """The fields of a command (action ``""``) or of one of its actions."""
    c = SCHEMA["commands"][cmd]
    if "actions" in c:
        return c["actions"][action]["fields"]
    return c["fields"]


def type_error(ty: Any, v: Any) -> Optional[str]:
    """Why ``v`` is not of schema type ``ty``, or ``None`` if it is."""
    number = isinstance(v, (int, float)) and not isinstance(v, bool)
    if v is None and ty != "number_pair" and not (isinstance(ty, dict) and "words" in ty):
        return None  # null: the daemon's default, as an absent field
    if ty == "number":
        ok = number and math.isfinite(v)
    elif ty == "integer":
        ok = isinstance(v, int) and not isinstance(v, bool) and v >= 0
    elif ty == "boolean":
        ok = isinstance(v, bool)
    elif ty in ("file_name", "name"):
        ok = isinstance(v, str)
    elif ty == "number_pair":
        ok = isinstance(v, list) and len(v) == 2 and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) for x in v
        )
    elif isinstance(ty, dict) and "word" in ty:
        ok = v in ty["word"]
    elif isinstance(ty, dict) and "words" in ty:
        ok = isinstance(v, list) and all(x in ty["words"] for x in v)
    else:
        return f"unknown schema type {ty!r}"
    return None if ok else f"{v!r} is not {ty}"


def check_request(req: Dict[str, Any]) -> List[Tuple[str, str, str]]:
    """The (cmd, action, field) entries a request uses, each checked."""
    cmd = req.get("cmd")
    assert cmd in SCHEMA["commands"], f"unknown command in {req}"
    c = SCHEMA["commands"][cmd]
    action = ""
    if "actions" in c:
        action = req.get("action") or c["default_action"]
        assert action in c["actions"], f"{cmd} has no action {action!r}: {req}"
    fields = schema_fields(cmd, action)
    used = [(cmd, action, "")]
    for k, v in req.items():
        if k in ("id", "cmd", "action"):
            continue
        assert k in fields, f"{cmd} {action} has no field {k!r} in the schema: {req}"
        err = type_error(fields[k], v)
        assert err is None, f"{cmd} {action} {k}: {err}"
        used.append((cmd, action, k))
    return used


class Recorder:
    """Every request line the fakes were sent, decoded."""

    def __init__(self) -> None:
        self.requests: List[Dict[str, Any]] = []
        self.job_log = "sample.csv"

    def reply(self, req: Dict[str, Any]) -> Dict[str, Any]:
        self.requests.append(json.loads(proto.encode(req)))
        cmd = req.get("cmd")
        r: Dict[str, Any] = {"id": req.get("id"), "ok": True}
        if cmd == "version":
            r["protocol"] = proto.PROTOCOL_VERSION
        elif cmd == "subscribe":
            r["subscribed"] = req.get("topics") or []
        elif cmd in ("characterize", "validate"):
            if req.get("action") in ("start", "resume") and req.get("log"):
                self.job_log = req["log"]
            r["job"] = {"kind": cmd, "log": self.job_log, "state": "done", "done": 1, "total": 1}
        return r


class FakeConnection:
    """Stands in for ``micropos.client.Connection``."""

    recorder = Recorder()

    def __init__(self, path: str, timeout: float) -> None:
        self.closed = False
        self._out: List[Dict[str, Any]] = []

    def send(self, req: Dict[str, Any], deadline: float) -> None:
        self._out.append(self.recorder.reply(req))

    def read(self, deadline: Optional[float]) -> Dict[str, Any]:
        return self._out.pop(0)

    def close(self) -> None:
        self.closed = True


class FakeAsyncConnection(FakeConnection):
    """Stands in for ``micropos.aio._Connection``."""

    @classmethod
    async def open(cls, path: str, timeout: float) -> "FakeAsyncConnection":
        return cls(path, timeout)

    async def send(self, req: Dict[str, Any], deadline: float) -> None:  # type: ignore[override]
        FakeConnection.send(self, req, deadline)

    async def read(self, deadline: Optional[float]) -> Dict[str, Any]:  # type: ignore[override]
        return FakeConnection.read(self, deadline)


SKIPPED_PARAMS = {"self", "timeout", "poll_s", "keepalive_s", "connect_timeout"}


def sample(name: str, hint: Any) -> Any:
    """A value of a parameter's type: every word of a list of keywords, the
    first word of a keyword, a plain file name for strings."""
    args = typing.get_args(hint)
    if typing.get_origin(hint) is typing.Union:
        hint = next(a for a in args if a is not type(None))
        args = typing.get_args(hint)
    origin = typing.get_origin(hint)
    if origin is typing.Literal:
        return args[0]
    if hint is bool:
        return True
    if hint is int:
        return 3
    if hint is float:
        return 2.5
    if hint is str:
        return "sample.csv"
    item = args[0] if args else None
    if typing.get_origin(item) is typing.Literal:
        return list(typing.get_args(item))
    if item is float:
        return [1.0, 2.0]
    raise AssertionError(f"no sample for parameter {name}: {hint!r}")


def calls(obj: Any) -> List[Tuple[str, Any, List[Dict[str, Any]]]]:
    """Each public method of ``obj`` with its argument sets: all optional
    arguments set, and only the required ones."""
    out = []
    for name, fn in inspect.getmembers(type(obj), inspect.isfunction):
        if name.startswith("_") or name in NOT_BUILDERS:
            continue
        sig = inspect.signature(fn)
        hints = typing.get_type_hints(fn)
        full: Dict[str, Any] = {}
        required: Dict[str, Any] = {}
        for p in sig.parameters.values():
            if p.name in SKIPPED_PARAMS:
                continue
            v = sample(p.name, hints[p.name])
            full[p.name] = v
            if p.default is inspect.Parameter.empty:
                required[p.name] = v
        out.append((name, getattr(obj, name), [full, required]))
    return out


def run_sync() -> List[Dict[str, Any]]:
    rec = FakeConnection.recorder = Recorder()
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(client, "Connection", FakeConnection)
        rig = client.Rig("/nonexistent/fake.sock")
        jobs = []
        for obj in (rig, rig.tables, rig.drift):
            for _, method, arg_sets in calls(obj):
                for kwargs in arg_sets:
                    r = method(**kwargs)
                    if isinstance(r, client.Job):
                        jobs.append(r)
                    if isinstance(r, client.Subscription):
                        r.close()
        assert jobs, "no method returned a job"
        for job in jobs:
            for _, method, arg_sets in calls(job):
                for kwargs in arg_sets:
                    method(**kwargs)
    return rec.requests


def run_async() -> List[Dict[str, Any]]:
    rec = FakeConnection.recorder = Recorder()

    async def drive() -> None:
        rig = aio.AsyncRig("/nonexistent/fake.sock")
        jobs = []
        for obj in (rig, rig.tables, rig.drift):
            for _, method, arg_sets in calls(obj):
                for kwargs in arg_sets:
                    r = await method(**kwargs)
                    if isinstance(r, aio.AsyncJob):
                        jobs.append(r)
                    if isinstance(r, aio.AsyncSubscription):
                        r.close()
        assert jobs, "no method returned a job"
        for job in jobs:
            for _, method, arg_sets in calls(job):
                for kwargs in arg_sets:
                    await method(**kwargs)
        await rig.close()

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(aio, "_Connection", FakeAsyncConnection)
        asyncio.run(drive())
    return rec.requests


def every_schema_entry() -> Set[Tuple[str, str, str]]:
    entries = set()
    for cmd, c in SCHEMA["commands"].items():
        actions = c.get("actions", {"": {"fields": c.get("fields", {})}})
        for action, a in actions.items():
            entries.add((cmd, action, ""))
            entries.update((cmd, action, f) for f in a["fields"])
    return entries


@pytest.mark.parametrize("run", [run_sync, run_async], ids=["sync", "asyncio"])
def test_every_request_is_in_the_schema_and_every_entry_is_sent(run):
    requests = run()
    assert len(requests) > 30, requests
    used: Set[Tuple[str, str, str]] = set()
    for req in requests:
        used.update(check_request(req))
    unreached = every_schema_entry() - used - set(UNREACHED)
    assert not unreached, f"the schema has entries no client method sends: {sorted(unreached)}"
    stale = set(UNREACHED) & used
    assert not stale, f"listed as unreached but sent: {sorted(stale)}"


def test_keyword_types_hold_the_schema_words():
    for alias, (cmd, action, field) in WORD_TYPES.items():
        ty = schema_fields(cmd, action)[field]
        words = ty.get("word") or ty.get("words")
        assert list(typing.get_args(getattr(types, alias))) == words, alias


def test_the_error_codes_are_the_schema_codes():
    assert set(SCHEMA["error_codes"]) == set(micropos.errors.ERROR_CLASSES)
    assert SCHEMA["protocol"] == proto.PROTOCOL_VERSION


def test_a_field_missing_from_the_schema_is_refused():
    """The check above can fail: a misspelt field is caught."""
    with pytest.raises(AssertionError, match="no field 'x_mu'"):
        check_request({"cmd": "move", "x_mu": 1.0})
    with pytest.raises(AssertionError, match="is not"):
        check_request({"cmd": "move", "mode": "fast"})
