"""Exceptions: one class per stable protocol error code, plus the client's own.

Why one class per code: lab scripts run for days and must react differently to
"the target is outside the travel" (a bug in the script) and "the camera
stalled" (retry later). ``except OutOfTravel:`` says that directly; the codes
themselves are the protocol's most stable part (``src/daemon/protocol/error.rs``,
docs/socket-protocol.md), so matching on them is safe across daemon versions.
The daemon's message is for people and may change; it is kept verbatim in
``.message``.

Every exception raised by this package is a :class:`MicroposError`, so one
``except MicroposError`` catches everything the rig can say. Client-side
conditions (:class:`ConnectionLost`, :class:`Timeout`, :class:`JobFailed`,
:class:`ProtocolError`) have codes of their own that never appear on the wire.
"""

from typing import Any, Dict, Mapping, Optional, Type

__all__ = [
    "MicroposError",
    # protocol codes
    "BadJson",
    "BadRequest",
    "RequestTooLarge",
    "NotAnObject",
    "MissingField",
    "WrongType",
    "BadValue",
    "UnknownCommand",
    "OutOfTravel",
    "NotReferenced",
    "NotConnected",
    "Busy",
    "Halted",
    "DriverError",
    "FaultLatched",
    "CameraUnavailable",
    "StaleMeasurement",
    "NotConverged",
    "NoActiveTable",
    "OutsideTable",
    "CameraStalled",
    "LowQuality",
    "RetryLimit",
    "Diverging",
    "NotAvailable",
    "JobState",
    "LogError",
    "PermissionDenied",
    "TimedOut",
    "ShuttingDown",
    "Internal",
    # client side
    "ConnectionLost",
    "DaemonUnreachable",
    "Timeout",
    "ProtocolError",
    "JobFailed",
    "JobCancelled",
    "ERROR_CLASSES",
    "error_from_reply",
]


class MicroposError(Exception):
    """Base of every error this package raises.

    Attributes:
        code: the stable machine-readable code (``"out_of_travel"``, …; for
            client-side errors ``"connection_lost"``, ``"timeout"``, …).
        message: the daemon's explanation, verbatim (or the client's).
        reply: the whole error reply line as received, when there was one
            (``None`` for client-side errors).
    """

    #: The code this class stands for; instances may carry another one when
    #: the daemon sent a code this client does not know yet.
    code: str = "unknown"

    def __init__(
        self,
        message: str,
        *,
        code: Optional[str] = None,
        reply: Optional[Mapping[str, Any]] = None,
    ) -> None:
        super().__init__(message)
        if code is not None:
            self.code = code
        self.message = message
        self.reply: Optional[Dict[str, Any]] = dict(reply) if reply is not None else None

    def __str__(self) -> str:
        return f"{self.code}: {self.message}"

    def __reduce__(self) -> Any:
        # Keep code and reply through pickling (multiprocessing, logging to
        # another process): the default would call __init__(message) only.
        return (_rebuild, (type(self), self.message, self.code, self.reply))


def _rebuild(
    cls: "Type[MicroposError]", message: str, code: str, reply: Optional[Dict[str, Any]]
) -> "MicroposError":
    return cls(message, code=code, reply=reply)


# --- one class per protocol error code (src/daemon/protocol/error.rs) -------


class BadJson(MicroposError):
    """The request line was not valid JSON (or not UTF-8)."""

    code = "bad_json"


class BadRequest(MicroposError):
    """The request named a key twice in one object (each key once, so that
    every reader of the line reads the same request)."""

    code = "bad_request"


class RequestTooLarge(MicroposError):
    """The request line exceeded the daemon's 65536-byte limit."""

    code = "request_too_large"


class NotAnObject(MicroposError):
    """The request was JSON but not an object."""

    code = "not_an_object"


class MissingField(MicroposError):
    """A required field was missing (e.g. ``move`` without ``x_um`` and ``y_um``)."""

    code = "missing_field"


class WrongType(MicroposError):
    """A field had the wrong JSON type (e.g. a string where a number belongs)."""

    code = "wrong_type"


class BadValue(MicroposError):
    """A field had the right type but an unusable value, or was unknown.

    Also raised by the client itself for values JSON cannot carry (NaN,
    infinity), before anything is sent.
    """

    code = "bad_value"


class UnknownCommand(MicroposError):
    """``cmd`` named no command this daemon knows."""

    code = "unknown_command"


class OutOfTravel(MicroposError):
    """A target was outside the soft limits or the travel; nothing moved."""

    code = "out_of_travel"


class NotReferenced(MicroposError):
    """An axis is not referenced: positions are unknown, moves are refused."""

    code = "not_referenced"


class NotConnected(MicroposError):
    """A controller is not connected (its line is down or not up yet)."""

    code = "not_connected"


class Busy(MicroposError):
    """The rig is busy: a job or a reference run owns the axes."""

    code = "busy"


class Halted(MicroposError):
    """The move was halted by ``stop`` or by a fault."""

    code = "halted"


class DriverError(MicroposError):
    """A controller or its line failed during the command."""

    code = "driver_error"


class FaultLatched(MicroposError):
    """A motion fault is latched (the message names it): motion is refused
    until ``reset()``, sent once its cause is found."""

    code = "fault_latched"


class CameraUnavailable(MicroposError):
    """The camera gives no usable measurement (or there is none)."""

    code = "camera_unavailable"


class StaleMeasurement(MicroposError):
    """The newest measurement is too old or of too low quality."""

    code = "stale_measurement"


class NotConverged(MicroposError):
    """A closed-loop move did not converge within its retries."""

    code = "not_converged"


class NoActiveTable(MicroposError):
    """A ``compensated`` move (or drift measurement) without an active table."""

    code = "no_active_table"


class OutsideTable(MicroposError):
    """A compensated target (a move or a validation pose) lies outside the area
    the table was characterized over, and the daemon's ``[compensation]
    outside_table = "refuse"``: nothing moved. The message names the area and
    the target. Move raw, characterize that area, or configure ``"warn"``.
    """

    code = "outside_table"


class CameraStalled(MicroposError):
    """No fresh frame arrived after the move settled within ``camera.timeout_ms``."""

    code = "camera_stalled"


class LowQuality(MicroposError):
    """Frames arrive but do not decode, or decode below ``camera.min_quality``."""

    code = "low_quality"


class RetryLimit(MicroposError):
    """Closed loop: the correction limit was reached outside tolerance."""

    code = "retry_limit"


class Diverging(MicroposError):
    """Closed loop: the residual grew, so the loop stopped instead of chasing it."""

    code = "diverging"


class NotAvailable(MicroposError):
    """The feature is in the protocol but not in this daemon build."""

    code = "not_available"


class JobState(MicroposError):
    """No such job, or the job is not in a state that allows the action."""

    code = "job_state"


class LogError(MicroposError):
    """The measurement log could not be created, read or resumed."""

    code = "log_error"


class PermissionDenied(MicroposError):
    """The client's role (the daemon's ``[access]`` groups) does not allow the
    command: e.g. ``move`` needs ``operate``, ``config`` needs ``admin``."""

    code = "permission_denied"


class TimedOut(MicroposError):
    """The daemon closed the connection: idle too long, or a request line was
    not finished in time. The request that meets it was not executed; the
    client closes the connection and the next call connects afresh."""

    code = "timed_out"


class ShuttingDown(MicroposError):
    """The daemon is shutting down; the connection closes after this."""

    code = "shutting_down"


class Internal(MicroposError):
    """A bug or an unexpected internal failure in the daemon."""

    code = "internal"


# --- client-side conditions --------------------------------------------------


class ConnectionLost(MicroposError, ConnectionError):
    """The connection to the daemon broke (or never came up).

    The request in flight may or may not have been executed: a move may still
    be running. Nothing is re-sent automatically; the next call on the same
    :class:`~micropos.Rig` connects afresh.
    """

    code = "connection_lost"


class DaemonUnreachable(ConnectionLost):
    """The daemon's socket could not be connected to (not running, wrong path,
    no permission)."""

    code = "daemon_unreachable"


class Timeout(MicroposError, TimeoutError):
    """No reply within the call's timeout.

    The daemon may still execute the request (a move keeps going). The client
    drops the connection, because the daemon answers a connection in order
    and the next request would queue behind the one still running, and
    reconnects on the next call.
    """

    code = "timeout"


class ProtocolError(MicroposError):
    """The daemon sent something this client cannot read (not JSON, not an
    object, or a protocol version it does not speak)."""

    code = "protocol_error"


class JobFailed(MicroposError):
    """A job ended without completing (``failed``; see :class:`JobCancelled`).

    Attributes:
        job: the job's last status object (``kind``, ``log``, ``state``,
            ``done``, ``total``, ``error``, …).
        state: the job's final state.
        error_code: the protocol error code that ended the job, when the
            daemon's ``job.error`` starts with one (``"camera_stalled: …"``,
            ``"not_referenced: …"``), so scripts can react as to a refusal;
            ``None`` otherwise.
    """

    code = "job_failed"

    def __init__(
        self,
        message: str,
        *,
        code: Optional[str] = None,
        reply: Optional[Mapping[str, Any]] = None,
        job: Optional[Mapping[str, Any]] = None,
    ) -> None:
        super().__init__(message, code=code, reply=reply)
        self.job: Dict[str, Any] = dict(job or {})
        self.state: str = str(self.job.get("state", ""))
        prefix = str(self.job.get("error") or "").split(":", 1)[0].strip()
        self.error_code: Optional[str] = prefix if prefix in ERROR_CLASSES else None

    def __reduce__(self) -> Any:
        return (_rebuild_job, (type(self), self.message, self.code, self.reply, self.job))


def _rebuild_job(
    cls: "Type[JobFailed]",
    message: str,
    code: str,
    reply: Optional[Dict[str, Any]],
    job: Dict[str, Any],
) -> "JobFailed":
    return cls(message, code=code, reply=reply, job=job)


class JobCancelled(JobFailed):
    """A job ended ``cancelled`` (``cancel``) or ``stopped`` (``stop``, a fault).

    Its log stays resumable (``characterize_resume``).
    """

    code = "job_cancelled"


#: Wire code → exception class, for every code in the protocol.
ERROR_CLASSES: Dict[str, Type[MicroposError]] = {
    cls.code: cls
    for cls in (
        BadJson,
        BadRequest,
        RequestTooLarge,
        NotAnObject,
        MissingField,
        WrongType,
        BadValue,
        UnknownCommand,
        OutOfTravel,
        NotReferenced,
        NotConnected,
        Busy,
        Halted,
        DriverError,
        FaultLatched,
        CameraUnavailable,
        StaleMeasurement,
        NotConverged,
        NoActiveTable,
        OutsideTable,
        CameraStalled,
        LowQuality,
        RetryLimit,
        Diverging,
        NotAvailable,
        JobState,
        LogError,
        PermissionDenied,
        TimedOut,
        ShuttingDown,
        Internal,
    )
}


def error_from_reply(reply: Mapping[str, Any]) -> MicroposError:
    """The exception for an ``"ok": false`` reply line.

    A code this client does not know (a newer daemon) still raises, as a plain
    :class:`MicroposError` carrying that code, rather than being lost.
    """
    err = reply.get("error")
    if not isinstance(err, Mapping):
        return ProtocolError(f"error reply without an error object: {reply!r}", reply=reply)
    code = str(err.get("code", "unknown"))
    message = str(err.get("message", ""))
    cls = ERROR_CLASSES.get(code, MicroposError)
    return cls(message, code=code, reply=reply)
