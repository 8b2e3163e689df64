"""The blocking client: :class:`Rig`, its job handles and event subscriptions.

Design, and why:

* One connection per :class:`Rig`, one request at a time (a lock), matched to
  its reply by ``id``. The daemon answers each connection in order, so
  pipelining would only make a slow call delay the next one.
* Every call has a deadline. On a timeout the connection is dropped (the
  daemon still works on the request, and the next one would queue behind it;
  a late reply would be discarded by ``id`` anyway) and the next call
  reconnects. A request is never re-sent by the client: a move that may
  have run must not run twice behind the script's back.
* :meth:`Rig.stop` uses a connection of its own, so it works while another
  thread waits on a long move, or from a signal handler that interrupted one.
* :meth:`Rig.subscribe` uses a connection of its own too: events never mix
  with replies, and a subscription that waits hours for a fault still notices
  a dead or frozen daemon (it pings with ``version`` when idle).
"""

import threading
import time
from typing import Any, Iterable, Iterator, List, Optional, Sequence, Type, cast

from . import _protocol as proto
from ._connection import Connection
from .errors import MicroposError, ProtocolError, Timeout
from .types import (
    Axes,
    CharacterizeMode,
    CharacterizePlan,
    GridApproach,
    GridOrder,
    DriftMethod,
    Json,
    JobKind,
    JobProgress,
    MoveMode,
    TableKind,
    Topic,
    ValidateMode,
    ValidateTest,
)

__all__ = ["Rig", "Job", "Subscription", "Tables", "Drift", "DEFAULT_SOCKET"]

#: Where a packaged microposd listens (``daemon.socket``).
DEFAULT_SOCKET = "/run/micropos/micropos.sock"

#: Default timeout of quick calls (status, position, tables list, …), s.
DEFAULT_TIMEOUT = 30.0
#: Default timeout of calls that wait for the stage or heavy work (a move with
#: ``wait``, ``reference``, ``tables build``, ``drift measure``, cancelling a
#: job, which finishes its current point first), s.
DEFAULT_LONG_TIMEOUT = 600.0


class Rig:
    """A connection to ``microposd``: every protocol command as a method.

    Replies are returned as the dictionaries the daemon sent
    (docs/socket-protocol.md); refusals raise the exception class of their
    error code (:mod:`micropos.errors`).

    Args:
        socket_path: the daemon's Unix socket.
        timeout: seconds any quick call may take before :class:`Timeout`.
        long_timeout: seconds a call that waits on the stage may take (moves
            with ``wait``, ``reference``, ``tables build``, ``drift measure``,
            job ``cancel``).

    Use as a context manager, or call :meth:`close`. Thread-safe: calls from
    several threads are serialized; :meth:`stop` overtakes them.
    """

    def __init__(
        self,
        socket_path: str = DEFAULT_SOCKET,
        timeout: float = DEFAULT_TIMEOUT,
        long_timeout: float = DEFAULT_LONG_TIMEOUT,
    ) -> None:
        if timeout <= 0 or long_timeout <= 0:
            raise ValueError("timeouts must be positive (a call without a deadline can hang)")
        self.socket_path = socket_path
        self.timeout = timeout
        self.long_timeout = long_timeout
        self._lock = threading.RLock()
        self._conn: Optional[Connection] = None
        self._next_id = 0
        #: The daemon's ``version`` reply from the latest (re)connection.
        self.daemon_version: Json = {}
        self.tables = Tables(self)
        self.drift = Drift(self)
        # Connect now: a wrong path or a daemon of another protocol version
        # should fail where the script opens the rig, not at its first move.
        with self._lock:
            self._connected()

    # --- plumbing -----------------------------------------------------------

    def __enter__(self) -> "Rig":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "connected" if self._conn is not None else "disconnected"
        return f"Rig({self.socket_path!r}, {state})"

    def close(self) -> None:
        """Closes the connection. Running moves and jobs go on in the daemon."""
        with self._lock:
            self._drop()

    def request(self, cmd: str, *, timeout: Optional[float] = None, **fields: Any) -> Json:
        """Sends any command with these fields (``None`` fields are left out)
        and returns the reply: for commands or fields newer than this client.
        """
        return self._call(proto.request(cmd, **fields), timeout)

    def _call(self, req: Json, timeout: Optional[float] = None) -> Json:
        limit = self.timeout if timeout is None else timeout
        with self._lock:
            return self._exchange(self._connected(), req, limit)

    def _connected(self) -> Connection:
        if self._conn is None or self._conn.closed:
            self._conn = None
            conn = Connection(self.socket_path, self.timeout)
            try:
                reply = self._exchange(conn, {"cmd": "version"}, self.timeout)
                proto.check_version(reply)
            except BaseException:
                conn.close()
                raise
            self._conn = conn
            self.daemon_version = reply
        return self._conn

    def _exchange(self, conn: Connection, req: Json, limit: float) -> Json:
        self._next_id += 1
        rid = self._next_id
        deadline = time.monotonic() + limit
        try:
            conn.send({**req, "id": rid}, deadline)
            while True:
                msg = conn.read(deadline)
                if proto.is_event(msg):
                    continue
                if msg.get("id") == rid:
                    return proto.check_reply(msg)
                err = proto.unsolicited_error(msg)
                if err is not None:
                    if err.code in ("shutting_down", "timed_out"):
                        conn.close()
                    raise err
        except Timeout:
            conn.close()
            raise Timeout(
                f"no reply to {req.get('cmd')!r} from {self.socket_path} within {limit:g} s; "
                "the daemon may still carry it out (a move keeps going: stop() halts it)"
            ) from None
        except MicroposError:
            raise
        except BaseException:
            # KeyboardInterrupt in the middle of a call: the daemon still
            # works on it, and the next request would queue behind it.
            conn.close()
            raise
        finally:
            if conn.closed and conn is self._conn:
                self._conn = None

    def _drop(self) -> None:
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    # --- commands -----------------------------------------------------------

    def version(self) -> Json:
        """``version``: daemon version, protocol version, command names."""
        return self._call({"cmd": "version"})

    def config(self) -> Json:
        """``config``: the daemon's effective configuration (``reply["config"]``)."""
        return self._call({"cmd": "config"})

    def status(self) -> Json:
        """``status``: rig mode, connection and reference state, faults,
        limits, camera, drift and the current or last job."""
        return self._call({"cmd": "status"})

    def position(self) -> Json:
        """``position``: positions by source (``commanded``, ``controller``,
        ``vision``), µm in stage coordinates."""
        return self._call({"cmd": "position"})

    def move(
        self,
        x_um: Optional[float] = None,
        y_um: Optional[float] = None,
        *,
        mode: MoveMode = "compensated",
        relative: bool = False,
        wait: bool = True,
        tolerance_um: Optional[float] = None,
        tool: Optional[str] = None,
        timeout: Optional[float] = None,
    ) -> Json:
        """``move``: one or both axes to a target (or by an offset).

        The defaults differ from the wire's (``raw``, no wait) on purpose: a
        script's move should be the accurate one and be finished when the
        call returns. Without an active table a compensated move raises
        :class:`~micropos.errors.NoActiveTable` rather than moving
        uncorrected; pass ``mode="raw"`` to move uncorrected.

        Args:
            x_um, y_um: target (or offset with ``relative``), µm; ``None``
                leaves that axis alone.
            mode: ``raw``, ``compensated`` or ``closed_loop``.
            relative: offsets from the commanded target.
            wait: return once on target (else once the controllers accepted).
            tolerance_um: closed loop: acceptable residual.
            tool: a ``[tools]`` name of the daemon's config: ``x_um``,
                ``y_um`` are where that tool should be (both, absolute,
                a planned mode); the reply's ``tool`` says the yaw used.
            timeout: seconds; default ``long_timeout`` with ``wait``.
        """
        req = proto.move(x_um, y_um, mode, relative, wait, tolerance_um, tool)
        return self._call(req, self._long(timeout) if wait else timeout)

    def stop(self) -> Json:
        """``stop``: halts both axes now, cancels the job, refuses queued moves.

        Sent on a connection of its own, so it is not queued behind a call
        another thread is waiting on.
        """
        deadline = time.monotonic() + self.timeout
        conn = Connection(self.socket_path, self.timeout)
        try:
            conn.send({"cmd": "stop", "id": "stop"}, deadline)
            while True:
                msg = conn.read(deadline)
                if msg.get("id") == "stop":
                    return proto.check_reply(msg)
                err = proto.unsolicited_error(msg)
                if err is not None:
                    raise err
        finally:
            conn.close()

    def reset(self) -> Json:
        """``reset``: acknowledges a latched fault (:class:`~micropos.errors.FaultLatched`)
        once its cause is found; motion is allowed again. ``cleared`` names
        the fault (``None`` if nothing was latched). An axis that lost its
        reference still needs :meth:`reference`."""
        return self._call({"cmd": "reset"})

    def reference(self, axes: Axes = "xy", *, timeout: Optional[float] = None) -> Json:
        """``reference``: reference run of ``x``, ``y`` or ``xy`` (the stage moves)."""
        return self._call(proto.reference(axes), self._long(timeout))

    def subscribe(
        self,
        topics: Optional[Iterable[Topic]] = None,
        *,
        timeout: Optional[float] = None,
        keepalive_s: Optional[float] = None,
    ) -> "Subscription":
        """``subscribe``: an iterator of events on a connection of its own.

        The subscription is active when this returns, so subscribe before
        starting what you want to watch.

        Args:
            topics: any of ``position``, ``job``, ``fault``, ``drift``;
                ``None`` = all.
            timeout: iteration raises :class:`Timeout` when no event arrived
                for this long (``None``: wait as long as the daemon is alive).
            keepalive_s: when no line arrived for this long, ask the daemon
                for its version; no answer within ``Rig.timeout`` raises
                :class:`Timeout`. Default: ``Rig.timeout``.
        """
        return Subscription(
            self.socket_path,
            topics,
            connect_timeout=self.timeout,
            timeout=timeout,
            keepalive_s=self.timeout if keepalive_s is None else keepalive_s,
        )

    # --- jobs ---------------------------------------------------------------

    def characterize(
        self,
        log: Optional[str] = None,
        *,
        axes: Optional[Axes] = None,
        step_um: Optional[float] = None,
        x_range_um: Optional[float] = None,
        y_range_um: Optional[float] = None,
        cycles: Optional[int] = None,
        frames_per_point: Optional[int] = None,
        settle_s: Optional[float] = None,
        drift_every_s: Optional[float] = None,
        drift_reference_um: Optional[Sequence[float]] = None,
        mode: Optional[CharacterizeMode] = None,
        velocity_um_per_s: Optional[float] = None,
        uncorrected_log: Optional[str] = None,
        moves_per_cycle: Optional[int] = None,
        anchor_spacing_um: Optional[float] = None,
        unanchored_log: Optional[str] = None,
        plan: Optional[CharacterizePlan] = None,
        pitch_um: Optional[float] = None,
        approach: Optional[GridApproach] = None,
        order: Optional[GridOrder] = None,
    ) -> "Job":
        """``characterize start``: a characterization job, logged point by
        point into ``log`` (a file name in the daemon's data directory).
        Unset parameters take the daemon's configured ``[characterize]``
        values. ``mode="sweep"`` measures on the fly: each axis sweeps at
        ``velocity_um_per_s`` (odd cycles) and twice it (even cycles; needs
        ``cycles`` ≥ 2), every frame is decoded, the camera delay is
        estimated from the data (``wait()["job"]["result"]["camera_delay_s"]``)
        and the log is written resampled onto the step grid when the sweep
        ends; ``uncorrected_log`` also writes it without the delay
        correction. The sweep stops at static anchors every
        ``anchor_spacing_um`` (default 250; 0 = none), measured as the step
        plan measures, and corrects its records to the step plan's motion
        state with them; ``unanchored_log`` also writes the log without that
        correction. ``moves_per_cycle`` (step mode) adds that many moves of
        varied length per cycle after the scans, so a model table can learn
        a lost motion that grows with the move length. ``plan="grid"``
        (step mode) measures every node of a lattice over both ranges,
        ``pitch_um`` apart (default ``step_um``), each reached from below on
        both axes (``approach="both"``: then from above too, a map per
        arrival direction; ``order="serpentine"`` with it: rows alternately
        in increasing and decreasing x); ``tables.build`` makes a 2-D map of
        it. Returns the job's handle."""
        reply = self._call(
            proto.characterize_start(
                log=log,
                axes=axes,
                step_um=step_um,
                x_range_um=x_range_um,
                y_range_um=y_range_um,
                cycles=cycles,
                frames_per_point=frames_per_point,
                settle_s=settle_s,
                drift_every_s=drift_every_s,
                drift_reference_um=drift_reference_um,
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
        )
        return Job._from_reply(self, "characterize", reply)

    def characterize_status(self) -> Json:
        """``characterize status``: the current or last characterization
        (``reply["job"]``, ``None`` if none ran)."""
        return self._call(proto.status_action("characterize"))

    def characterize_cancel(self) -> Json:
        """``characterize cancel``: ends the running job after its current
        point; the log stays resumable."""
        return self._call(proto.cancel_action("characterize"), self.long_timeout)

    def characterize_resume(self, log: str) -> "Job":
        """``characterize resume``: continues the job logged in ``log``."""
        reply = self._call({"cmd": "characterize", "action": "resume", "log": log})
        return Job._from_reply(self, "characterize", reply)

    def validate(
        self,
        test: Optional[ValidateTest] = None,
        *,
        modes: Optional[Iterable[ValidateMode]] = None,
        cycles: Optional[int] = None,
        log: Optional[str] = None,
        origin_x_um: Optional[float] = None,
        origin_y_um: Optional[float] = None,
        square_step_um: Optional[float] = None,
        table: Optional[str] = None,
        model_table: Optional[str] = None,
        frames_per_point: Optional[int] = None,
        settle_s: Optional[float] = None,
    ) -> "Job":
        """``validate start``: the paper's square and/or random targets in the
        given modes; ISO 9283 AP/RP per pose. Returns the job's handle;
        ``wait()`` returns the final status with ``validation.results``."""
        reply = self._call(
            proto.validate_start(
                test=test,
                modes=modes,
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
        )
        return Job._from_reply(self, "validate", reply)

    def validate_status(self) -> Json:
        """``validate status``: progress, and ``validation`` results when done."""
        return self._call(proto.status_action("validate"))

    def validate_cancel(self) -> Json:
        """``validate cancel``: ends the validation between poses."""
        return self._call(proto.cancel_action("validate"), self.long_timeout)

    def figures(self, job: JobKind = "characterize", log: Optional[str] = None) -> Json:
        """``figures``: the paper's figures of the newest ``job`` log (or of
        ``log``) as data: ``figures`` (panels and traces, as ``micropos plot``
        draws them), a summary (``axes`` with backlash, largest errors and RP
        for a characterization; ``results`` with ISO 9283 AP/RP per test and
        mode for a validation) and ``notes``. No such log yet, or one that
        does not read, raises :class:`LogError`."""
        return self._call(proto.figures(job, log), self.long_timeout)

    def current_job(self) -> "Optional[Job]":
        """A handle on the daemon's current or last job (from ``status``), for
        a script that reconnects to a job it started earlier; ``None`` if no
        job ran since the daemon started."""
        job = self.status().get("job")
        if not isinstance(job, dict):
            return None
        return Job(self, job["kind"], job["log"], {"ok": True, "job": job})

    def _long(self, timeout: Optional[float]) -> float:
        return self.long_timeout if timeout is None else timeout


class Tables:
    """``tables``: compensation table files in the daemon's data directory
    (``rig.tables``)."""

    def __init__(self, rig: Rig) -> None:
        self._rig = rig

    def list(self) -> Json:
        """``tables list``: ``files``, ``loaded``, ``active``."""
        return self._rig._call({"cmd": "tables", "action": "list"})

    def load(self, name: str) -> Json:
        """``tables load``: loads a table file by name (not yet active)."""
        return self._rig._call({"cmd": "tables", "action": "load", "name": name})

    def activate(self, name: Optional[str]) -> Json:
        """``tables activate``: makes a loaded table the one ``compensated``
        moves use, swapped without restart; ``None`` deactivates."""
        return self._rig._call(proto.tables_activate(name))

    def build(
        self,
        log: str,
        *,
        name: Optional[str] = None,
        kinds: Optional[Iterable[TableKind]] = None,
        activate: bool = False,
        timeout: Optional[float] = None,
    ) -> Json:
        """``tables build``: the paper's lookup tables (``STEM-paper.toml``)
        and a fitted-model table (``STEM-model.toml``) from a characterization
        log, or a 2-D map (``STEM-grid.toml``) from a grid log, written and
        loaded by the daemon; ``activate`` makes the first one active."""
        req = proto.tables_build(log, name, kinds, activate)
        return self._rig._call(req, self._rig._long(timeout))


class Drift:
    """``drift``: live drift correction (``rig.drift``)."""

    def __init__(self, rig: Rig) -> None:
        self._rig = rig

    def show(self) -> Json:
        """``drift show``: the live drift state (``reply["drift"]``)."""
        return self._rig._call({"cmd": "drift", "action": "show"})

    def set(
        self,
        method: Optional[DriftMethod] = None,
        *,
        every_s: Optional[float] = None,
        time_constant_s: Optional[float] = None,
    ) -> Json:
        """``drift set``: method and/or intervals; unset fields stay."""
        return self._rig._call(proto.drift_set(method, every_s, time_constant_s))

    def reset(self) -> Json:
        """``drift reset``: forgets the re-measurements; the next compensated
        move measures."""
        return self._rig._call({"cmd": "drift", "action": "reset"})

    def measure(self, *, timeout: Optional[float] = None) -> Json:
        """``drift measure``: re-measures the reference now with the active
        table (the stage moves); refused while a job runs."""
        return self._rig._call({"cmd": "drift", "action": "measure"}, self._rig._long(timeout))


class Job:
    """A characterization or validation job in the daemon.

    The job runs in the daemon whatever happens to this handle or to the
    script; a characterization's log stays resumable.

    Attributes:
        kind: ``characterize`` or ``validate``.
        log: the job's log file name (identifies the job).
        started: the reply that started (or found) the job.
    """

    def __init__(self, rig: Rig, kind: JobKind, log: str, started: Json) -> None:
        self._rig = rig
        self.kind: JobKind = kind
        self.log = log
        self.started = started

    @classmethod
    def _from_reply(cls: "Type[Job]", rig: Rig, kind: JobKind, reply: Json) -> "Job":
        job = reply.get("job")
        if not isinstance(job, dict) or not isinstance(job.get("log"), str):
            raise ProtocolError(f"{kind} reply without job.log: {reply!r}", reply=reply)
        return cls(rig, kind, job["log"], reply)

    def __repr__(self) -> str:
        return f"Job({self.kind!r}, log={self.log!r})"

    def status(self) -> Json:
        """The whole ``characterize``/``validate`` status reply (for a
        validation, with ``validation`` results once done)."""
        reply = self._rig._call(proto.status_action(self.kind))
        proto.job_of(reply, self.kind, self.log)
        return reply

    @property
    def progress(self) -> JobProgress:
        """The job's status object, read from the daemon now: ``state``,
        ``done``, ``total``, ``eta_s``, ``error``, ``retries``."""
        reply = self._rig._call(proto.status_action(self.kind))
        return cast(JobProgress, proto.job_of(reply, self.kind, self.log))

    def wait(self, timeout: Optional[float] = None, poll_s: float = 1.0) -> Json:
        """Polls until the job ends; returns the final status reply.

        Raises:
            JobCancelled: it ended ``cancelled`` or ``stopped``.
            JobFailed: it ended ``failed`` (``.job["error"]`` says why).
            Timeout: it still runs after ``timeout`` seconds (it goes on).
            ConnectionLost: the daemon went away (the job's log stays).
        """
        if poll_s <= 0:
            raise ValueError("poll_s must be positive")
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            reply = self.status()
            job = reply["job"]
            if job.get("state") in proto.FINAL_STATES:
                proto.raise_if_unsuccessful(job, reply)
                return reply
            pause = poll_s
            if deadline is not None:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise Timeout(
                        f"{self.kind} job {self.log!r} still {job.get('state')} after "
                        f"{timeout:g} s ({job.get('done')}/{job.get('total')}); it goes on"
                    )
                pause = min(pause, left)
            time.sleep(pause)

    def cancel(self) -> Json:
        """Cancels the job (after its current point or pose)."""
        self.status()  # refuse to cancel someone else's job
        return self._rig._call(proto.cancel_action(self.kind), self._rig.long_timeout)


class Subscription(Iterator[Json]):
    """Events of a ``subscribe``, on a connection of its own.

    Iterate it (``for event in sub``), or call :meth:`next` with a timeout.
    Every event is yielded, ``lagged`` included (the daemon drops events for a
    slow reader and says how many). A dead daemon raises
    :class:`~micropos.errors.ConnectionLost`; a frozen one
    :class:`~micropos.errors.Timeout` (keepalive); a stopping one
    :class:`~micropos.errors.ShuttingDown`. Close it (or use ``with``).
    """

    def __init__(
        self,
        socket_path: str,
        topics: Optional[Iterable[Topic]],
        *,
        connect_timeout: float,
        timeout: Optional[float],
        keepalive_s: float,
    ) -> None:
        if keepalive_s <= 0:
            raise ValueError("keepalive_s must be positive")
        self._timeout = timeout
        self._reply_timeout = connect_timeout
        self._keepalive_s = keepalive_s
        self._pending: List[Json] = []
        self._ping_id = 0
        self._ping_sent: Optional[float] = None
        self._conn = Connection(socket_path, connect_timeout)
        try:
            deadline = time.monotonic() + connect_timeout
            self._conn.send({**proto.subscribe(topics), "id": "subscribe"}, deadline)
            while True:
                msg = self._conn.read(deadline)
                if proto.is_event(msg):
                    # The daemon may push the first events before its reply.
                    self._pending.append(msg)
                    continue
                if msg.get("id") == "subscribe":
                    reply = proto.check_reply(msg)
                    break
                err = proto.unsolicited_error(msg)
                if err is not None:
                    raise err
        except BaseException:
            self._conn.close()
            raise
        #: The topics the daemon confirmed.
        self.topics: List[str] = proto.topics_list(reply)
        self._last_heard = time.monotonic()

    def __enter__(self) -> "Subscription":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def __iter__(self) -> "Subscription":
        return self

    def __next__(self) -> Json:
        if self._conn.closed and not self._pending:
            raise StopIteration
        return self.next(self._timeout)

    def close(self) -> None:
        """Ends the subscription (closes its connection); iteration stops."""
        self._conn.close()

    def next(self, timeout: Optional[float] = None) -> Json:
        """The next event; :class:`Timeout` if none arrives within ``timeout``
        seconds (``None``: as long as the daemon answers keepalives)."""
        if self._pending:
            return self._pending.pop(0)
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            now = time.monotonic()
            if self._ping_sent is not None:
                wake = self._ping_sent + self._reply_timeout
            else:
                wake = self._last_heard + self._keepalive_s
            if deadline is not None and deadline < wake:
                wake = deadline
            try:
                msg = self._conn.read(wake)
            except Timeout:
                now = time.monotonic()
                if deadline is not None and now >= deadline:
                    raise Timeout(f"no event within {timeout:g} s") from None
                if self._ping_sent is not None and now >= self._ping_sent + self._reply_timeout:
                    self.close()
                    raise Timeout(
                        f"the daemon did not answer a keepalive within {self._reply_timeout:g} s"
                    ) from None
                if self._ping_sent is None and now >= self._last_heard + self._keepalive_s:
                    self._ping_id += 1
                    self._ping_sent = now
                    self._conn.send(
                        {"cmd": "version", "id": f"keepalive-{self._ping_id}"},
                        now + self._reply_timeout,
                    )
                continue
            except MicroposError:
                self.close()
                raise
            self._last_heard = time.monotonic()
            if proto.is_event(msg):
                return msg
            err = proto.unsolicited_error(msg)
            if err is not None:
                self.close()
                raise err
            # A keepalive answer: the daemon is alive.
            self._ping_sent = None
