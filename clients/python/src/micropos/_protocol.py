"""The wire format, without I/O: request objects, line encoding, reply checks.

Why separate from the sync and asyncio clients: both must send byte-identical
requests and judge replies identically; keeping the field names here, in one
place, means a renamed field is fixed once. They are checked against the
daemon's request schema (``docs/socket-schema.json``, generated from
``src/daemon/protocol/schema.rs``) by ``tests/test_schema.py``. Every builder drops the arguments left at ``None`` so the daemon applies
its own (configured) default instead of a copy of it frozen in this client.
"""

import json
import math
from typing import Any, Iterable, List, Mapping, Optional, Sequence

from .errors import (
    BadValue,
    JobCancelled,
    JobFailed,
    JobState,
    MicroposError,
    ProtocolError,
    error_from_reply,
)
from .types import Axes, DriftMethod, JobKind, Json, MoveMode, ValidateTest

#: The protocol version this client speaks (``version`` → ``protocol``).
PROTOCOL_VERSION = 1

#: Longest reply line accepted, bytes. Validation results are the largest
#: replies (a few hundred kB for long runs); anything beyond this is not a
#: reply but a runaway stream, and is refused rather than buffered forever.
MAX_LINE_BYTES = 64 * 1024 * 1024

#: Job states after which nothing changes any more.
FINAL_STATES = frozenset({"done", "cancelled", "stopped", "failed"})


def request(cmd: str, **fields: Any) -> Json:
    """A request object: ``cmd`` plus every field that is not ``None``."""
    req: Json = {"cmd": cmd}
    req.update({k: v for k, v in fields.items() if v is not None})
    return req


def encode(req: Mapping[str, Any]) -> bytes:
    """One request line, UTF-8, newline-terminated.

    NaN and infinities have no JSON spelling; sending Python's ``NaN`` token
    would earn a ``bad_json`` that does not say which argument was wrong, so
    they are refused here as :class:`BadValue` naming the field.
    """
    try:
        text = json.dumps(req, allow_nan=False, separators=(",", ":"), ensure_ascii=False)
    except ValueError:
        bad = [k for k, v in req.items() if _non_finite(v)]
        raise BadValue(
            f"{', '.join(bad) or 'a field'} must be a finite number "
            f"(NaN and infinity cannot be sent), got {req!r}"
        ) from None
    except TypeError as e:
        raise BadValue(f"request cannot be encoded as JSON: {e}") from None
    return text.encode("utf-8") + b"\n"


def _non_finite(v: Any) -> bool:
    if isinstance(v, float):
        return not math.isfinite(v)
    if isinstance(v, (list, tuple)):
        return any(_non_finite(x) for x in v)
    return False


def decode(line: bytes) -> Json:
    """One received line as a JSON object, or :class:`ProtocolError`."""
    try:
        value = json.loads(line)
    except (UnicodeDecodeError, ValueError) as e:
        raise ProtocolError(
            f"the daemon sent a line that is not JSON ({e}): {line[:200]!r}"
        ) from None
    if not isinstance(value, dict):
        raise ProtocolError(f"the daemon sent a line that is not an object: {line[:200]!r}")
    return value


def is_event(msg: Mapping[str, Any]) -> bool:
    """Pushed events carry ``event`` and never ``id``/``ok``."""
    return "event" in msg and "ok" not in msg


def check_reply(msg: Json) -> Json:
    """The reply itself when ``ok``; the matching exception otherwise."""
    if msg.get("ok") is True:
        return msg
    if msg.get("ok") is False:
        raise error_from_reply(msg)
    raise ProtocolError(f"reply without ok true/false: {msg!r}")


def unsolicited_error(msg: Mapping[str, Any]) -> Optional[MicroposError]:
    """An error line with ``id`` null is the daemon speaking without being
    asked for that id: ``shutting_down`` on the way out, or the answer to a
    line it could not parse far enough to read an ``id`` (``bad_json``,
    ``request_too_large``). With one request in flight, it is that request's
    answer (or the end of the connection); returned so callers raise it."""
    if msg.get("ok") is False and msg.get("id") is None:
        return error_from_reply(msg)
    return None


def check_version(reply: Mapping[str, Any]) -> None:
    """Refuses a daemon whose protocol major version this client does not know
    (the protocol's rule: a client refuses a version it does not speak)."""
    version = reply.get("protocol")
    if version != PROTOCOL_VERSION:
        raise ProtocolError(
            f"the daemon speaks socket protocol {version!r}; this client speaks "
            f"{PROTOCOL_VERSION} (upgrade the micropos Python package or the daemon)"
        )


# --- request builders, one per command and action ---------------------------


def move(
    x_um: Optional[float],
    y_um: Optional[float],
    mode: MoveMode,
    relative: bool,
    wait: bool,
    tolerance_um: Optional[float],
    tool: Optional[str] = None,
) -> Json:
    """``move``: every flag is sent explicitly, so the request says what the
    script meant whatever the wire defaults are. ``tool``: the target is
    where that ``[tools]`` point should be."""
    return request(
        "move",
        x_um=x_um,
        y_um=y_um,
        mode=mode,
        relative=relative,
        wait=wait,
        tolerance_um=tolerance_um,
        tool=tool,
    )


def reference(axes: Axes) -> Json:
    """``reference``."""
    return request("reference", axes=axes)


def subscribe(topics: Optional[Iterable[str]]) -> Json:
    """``subscribe``; ``None`` = every topic (the daemon's default)."""
    if isinstance(topics, str):
        # A bare string would be split into letters: a classic slip.
        topics = [topics]
    return request("subscribe", topics=None if topics is None else list(topics))


def characterize_start(
    *,
    log: Optional[str],
    axes: Optional[Axes],
    step_um: Optional[float],
    x_range_um: Optional[float],
    y_range_um: Optional[float],
    cycles: Optional[int],
    frames_per_point: Optional[int],
    settle_s: Optional[float],
    drift_every_s: Optional[float],
    drift_reference_um: Optional[Sequence[float]],
    mode: Optional[str] = None,
    velocity_um_per_s: Optional[float] = None,
    uncorrected_log: Optional[str] = None,
    moves_per_cycle: Optional[int] = None,
    anchor_spacing_um: Optional[float] = None,
    unanchored_log: Optional[str] = None,
    plan: Optional[str] = None,
    pitch_um: Optional[float] = None,
    approach: Optional[str] = None,
    order: Optional[str] = None,
) -> Json:
    """``characterize`` ``start``."""
    return request(
        "characterize",
        action="start",
        log=log,
        axes=axes,
        step_um=step_um,
        x_range_um=x_range_um,
        y_range_um=y_range_um,
        cycles=cycles,
        frames_per_point=frames_per_point,
        settle_s=settle_s,
        drift_every_s=drift_every_s,
        drift_reference_um=None if drift_reference_um is None else list(drift_reference_um),
        mode=mode,
        velocity_um_per_s=velocity_um_per_s,
        uncorrected_log=uncorrected_log,
        moves_per_cycle=moves_per_cycle,
        anchor_spacing_um=anchor_spacing_um,
        unanchored_log=unanchored_log,
        plan=plan,
        pitch_um=pitch_um,
        approach=approach,
        order=order,
    )


def validate_start(
    *,
    test: Optional[ValidateTest],
    modes: Optional[Iterable[str]],
    cycles: Optional[int],
    log: Optional[str],
    origin_x_um: Optional[float],
    origin_y_um: Optional[float],
    square_step_um: Optional[float],
    table: Optional[str],
    model_table: Optional[str],
    frames_per_point: Optional[int],
    settle_s: Optional[float],
) -> Json:
    """``validate`` ``start``."""
    if isinstance(modes, str):
        modes = [modes]
    return request(
        "validate",
        action="start",
        test=test,
        modes=None if modes is None else list(modes),
        cycles=cycles,
        log=log,
        origin_x_um=origin_x_um,
        origin_y_um=origin_y_um,
        square_step_um=square_step_um,
        table=table,
        model_table=model_table,
        frames_per_point=frames_per_point,
        settle_s=settle_s,
    )


def tables_build(
    log: str, name: Optional[str], kinds: Optional[Iterable[str]], activate: bool
) -> Json:
    """``tables`` ``build``."""
    if isinstance(kinds, str):
        kinds = [kinds]
    return request(
        "tables",
        action="build",
        log=log,
        name=name,
        kinds=None if kinds is None else list(kinds),
        activate=activate,
    )


def tables_activate(name: Optional[str]) -> Json:
    """``tables`` ``activate``; ``name`` ``None`` is sent as null: deactivate."""
    return {"cmd": "tables", "action": "activate", "name": name}


def drift_set(
    method: Optional[DriftMethod], every_s: Optional[float], time_constant_s: Optional[float]
) -> Json:
    """``drift`` ``set``; fields left ``None`` keep their current value."""
    return request(
        "drift", action="set", method=method, every_s=every_s, time_constant_s=time_constant_s
    )


def figures(job: JobKind, log: Optional[str]) -> Json:
    """``figures``: the paper's figures of a job's log; ``log`` ``None`` = the
    newest log of that job in the daemon's data directory."""
    return request("figures", job=job, log=log)


# --- jobs ---------------------------------------------------------------------


def job_of(reply: Mapping[str, Any], kind: str, log: str) -> Json:
    """The ``job`` object of a status reply, checked to be the job a handle
    follows: one job runs at a time, and a later job replaces the earlier one
    in ``status``; reading its progress as ours would be a silent mix-up."""
    job = reply.get("job")
    if not isinstance(job, dict):
        raise JobState(f"the daemon reports no {kind} job (was it restarted?)", reply=reply)
    if job.get("kind") != kind or job.get("log") != log:
        raise JobState(
            f"the daemon's current job is {job.get('kind')} {job.get('log')!r}, "
            f"not the {kind} {log!r} this handle follows",
            reply=reply,
        )
    return job


def raise_if_unsuccessful(job: Mapping[str, Any], reply: Mapping[str, Any]) -> None:
    """A finished job that did not complete raises, so that ``wait()`` never
    returns a cancelled or failed job as if its results were there."""
    state = job.get("state")
    if state == "done":
        return
    what = f"{job.get('kind')} job {job.get('log')!r} {state}"
    detail = job.get("error")
    message = f"{what}: {detail}" if detail else what
    cls = JobCancelled if state in ("cancelled", "stopped") else JobFailed
    raise cls(message, reply=reply, job=job)


def status_action(kind: str) -> Json:
    """``characterize``/``validate`` ``status``."""
    return {"cmd": kind, "action": "status"}


def cancel_action(kind: str) -> Json:
    """``characterize``/``validate`` ``cancel``."""
    return {"cmd": kind, "action": "cancel"}


def topics_list(reply: Mapping[str, Any]) -> List[str]:
    """The topics the daemon confirmed."""
    return [str(t) for t in reply.get("subscribed", [])]

