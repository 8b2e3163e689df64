"""The asyncio client: :class:`AsyncRig`, method for method :class:`~micropos.Rig`.

Why a second client rather than running the blocking one in threads: an
asyncio application (a GUI, a lab orchestrator watching several rigs) wants
to await a move while it keeps serving events, and to cancel a wait. The
semantics are those of :mod:`micropos.client` (one request at a time per
connection, a deadline on every call, connection dropped on timeout or
cancellation, ``stop`` and ``subscribe`` on connections of their own); only
the I/O differs. Request building and reply checks are shared
(:mod:`micropos._protocol`).
"""

import asyncio
import time
from typing import Any, AsyncIterator, Awaitable, Iterable, List, Optional, Sequence, Type, cast

from . import _protocol as proto
from .client import DEFAULT_LONG_TIMEOUT, DEFAULT_SOCKET, DEFAULT_TIMEOUT
from .errors import ConnectionLost, DaemonUnreachable, MicroposError, ProtocolError, Timeout
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

__all__ = ["AsyncRig", "AsyncJob", "AsyncSubscription", "AsyncTables", "AsyncDrift"]


class _Connection:
    """One asyncio Unix-socket connection reading whole lines with deadlines."""

    def __init__(self, path: str, reader: asyncio.StreamReader, writer: asyncio.StreamWriter):
        self.path = path
        self._r = reader
        self._w = writer
        self.closed = False

    @classmethod
    async def open(cls, path: str, timeout: float) -> "_Connection":
        try:
            r, w = await asyncio.wait_for(
                asyncio.open_unix_connection(path, limit=proto.MAX_LINE_BYTES), timeout
            )
        except asyncio.TimeoutError:
            raise DaemonUnreachable(
                f"connecting to {path} took longer than {timeout} s (daemon overloaded or stopped?)"
            ) from None
        except OSError as e:
            raise DaemonUnreachable(
                f"cannot connect to the micropos daemon at {path}: {e.strerror or e}"
                " (is microposd running, is this its socket, may this user open it?)"
            ) from None
        return cls(path, r, w)

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self._w.close()

    async def send(self, req: Json, deadline: float) -> None:
        data = proto.encode(req)
        if self.closed:
            raise ConnectionLost(f"the connection to {self.path} is closed")
        try:
            self._w.write(data)
            await asyncio.wait_for(self._w.drain(), _remaining(deadline))
        except asyncio.TimeoutError:
            self.close()
            raise Timeout(f"the daemon at {self.path} did not accept a request in time") from None
        except OSError as e:
            self.close()
            raise ConnectionLost(f"connection to {self.path} lost while sending: {e}") from None

    async def read(self, deadline: Optional[float]) -> Json:
        while True:
            if self.closed:
                raise ConnectionLost(f"the connection to {self.path} is closed")
            try:
                if deadline is None:
                    line = await self._r.readline()
                else:
                    line = await asyncio.wait_for(self._r.readline(), _remaining(deadline))
            except asyncio.TimeoutError:
                raise Timeout(f"no answer from the daemon at {self.path} in time") from None
            except OSError as e:
                self.close()
                raise ConnectionLost(f"connection to {self.path} lost: {e}") from None
            except ValueError:
                self.close()
                raise ProtocolError(
                    f"a line from {self.path} exceeds {proto.MAX_LINE_BYTES} bytes"
                ) from None
            if not line.endswith(b"\n"):
                self.close()
                raise ConnectionLost(f"the daemon at {self.path} closed the connection")
            if line.strip():
                return proto.decode(line)


def _remaining(deadline: float) -> float:
    return max(deadline - time.monotonic(), 1e-3)


class AsyncRig:
    """The asyncio twin of :class:`~micropos.Rig`; every method is a coroutine.

    Open it with ``async with AsyncRig(path) as rig:`` or
    ``rig = await AsyncRig.connect(path)``; close with ``await rig.close()``.
    Arguments, defaults and exceptions are those of :class:`~micropos.Rig`.
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
        # Created on first use: before 3.10 a Lock binds the loop it is made in.
        self._lock: Optional[asyncio.Lock] = None
        self._conn: Optional[_Connection] = None
        self._next_id = 0
        #: The daemon's ``version`` reply from the latest (re)connection.
        self.daemon_version: Json = {}
        self.tables = AsyncTables(self)
        self.drift = AsyncDrift(self)

    @classmethod
    async def connect(
        cls,
        socket_path: str = DEFAULT_SOCKET,
        timeout: float = DEFAULT_TIMEOUT,
        long_timeout: float = DEFAULT_LONG_TIMEOUT,
    ) -> "AsyncRig":
        """A connected rig (the version handshake done)."""
        rig = cls(socket_path, timeout, long_timeout)
        async with rig._locked():
            await rig._connected()
        return rig

    async def __aenter__(self) -> "AsyncRig":
        async with self._locked():
            await self._connected()
        return self

    async def __aexit__(self, *exc: Any) -> None:
        await self.close()

    def __repr__(self) -> str:
        state = "connected" if self._conn is not None else "disconnected"
        return f"AsyncRig({self.socket_path!r}, {state})"

    async def close(self) -> None:
        """Closes the connection. Running moves and jobs go on in the daemon."""
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    def _locked(self) -> asyncio.Lock:
        if self._lock is None:
            self._lock = asyncio.Lock()
        return self._lock

    async def request(self, cmd: str, *, timeout: Optional[float] = None, **fields: Any) -> Json:
        """Any command with these fields (``None`` left out); see :meth:`Rig.request`."""
        return await self._call(proto.request(cmd, **fields), timeout)

    async def _call(self, req: Json, timeout: Optional[float] = None) -> Json:
        limit = self.timeout if timeout is None else timeout
        async with self._locked():
            return await self._exchange(await self._connected(), req, limit)

    async def _connected(self) -> _Connection:
        if self._conn is None or self._conn.closed:
            self._conn = None
            conn = await _Connection.open(self.socket_path, self.timeout)
            try:
                reply = await self._exchange(conn, {"cmd": "version"}, self.timeout)
                proto.check_version(reply)
            except BaseException:
                conn.close()
                raise
            self._conn = conn
            self.daemon_version = reply
        return self._conn

    async def _exchange(self, conn: _Connection, req: Json, limit: float) -> Json:
        self._next_id += 1
        rid = self._next_id
        deadline = time.monotonic() + limit
        try:
            await conn.send({**req, "id": rid}, deadline)
            while True:
                msg = await conn.read(deadline)
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
            # Cancelled mid-call: the daemon still works on the request, and
            # the next one would queue behind it on this connection.
            conn.close()
            raise
        finally:
            if conn.closed and conn is self._conn:
                self._conn = None

    def _long(self, timeout: Optional[float]) -> float:
        return self.long_timeout if timeout is None else timeout

    # --- commands -----------------------------------------------------------

    async def version(self) -> Json:
        """``version``."""
        return await self._call({"cmd": "version"})

    async def config(self) -> Json:
        """``config``."""
        return await self._call({"cmd": "config"})

    async def status(self) -> Json:
        """``status``."""
        return await self._call({"cmd": "status"})

    async def position(self) -> Json:
        """``position``."""
        return await self._call({"cmd": "position"})

    async def move(
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
        """``move``; see :meth:`Rig.move` (same defaults: compensated, wait)."""
        req = proto.move(x_um, y_um, mode, relative, wait, tolerance_um, tool)
        return await self._call(req, self._long(timeout) if wait else timeout)

    async def stop(self) -> Json:
        """``stop``, on a connection of its own (never queued behind a move)."""
        deadline = time.monotonic() + self.timeout
        conn = await _Connection.open(self.socket_path, self.timeout)
        try:
            await conn.send({"cmd": "stop", "id": "stop"}, deadline)
            while True:
                msg = await conn.read(deadline)
                if msg.get("id") == "stop":
                    return proto.check_reply(msg)
                err = proto.unsolicited_error(msg)
                if err is not None:
                    raise err
        finally:
            conn.close()

    async def reset(self) -> Json:
        """``reset``: acknowledges a latched fault (see :meth:`micropos.Rig.reset`)."""
        return await self._call({"cmd": "reset"})

    async def reference(self, axes: Axes = "xy", *, timeout: Optional[float] = None) -> Json:
        """``reference``."""
        return await self._call(proto.reference(axes), self._long(timeout))

    async def subscribe(
        self,
        topics: Optional[Iterable[Topic]] = None,
        *,
        timeout: Optional[float] = None,
        keepalive_s: Optional[float] = None,
    ) -> "AsyncSubscription":
        """``subscribe``: an async iterator of events on a connection of its
        own, active when this returns; see :meth:`Rig.subscribe`."""
        return await AsyncSubscription._open(
            self.socket_path,
            topics,
            connect_timeout=self.timeout,
            timeout=timeout,
            keepalive_s=self.timeout if keepalive_s is None else keepalive_s,
        )

    async def characterize(
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
    ) -> "AsyncJob":
        """``characterize start``; see :meth:`Rig.characterize`."""
        reply = await self._call(
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
        return AsyncJob._from_reply(self, "characterize", reply)

    async def characterize_status(self) -> Json:
        """``characterize status``."""
        return await self._call(proto.status_action("characterize"))

    async def characterize_cancel(self) -> Json:
        """``characterize cancel``."""
        return await self._call(proto.cancel_action("characterize"), self.long_timeout)

    async def characterize_resume(self, log: str) -> "AsyncJob":
        """``characterize resume``."""
        reply = await self._call({"cmd": "characterize", "action": "resume", "log": log})
        return AsyncJob._from_reply(self, "characterize", reply)

    async def validate(
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
    ) -> "AsyncJob":
        """``validate start``; see :meth:`Rig.validate`."""
        reply = await self._call(
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
        return AsyncJob._from_reply(self, "validate", reply)

    async def validate_status(self) -> Json:
        """``validate status``."""
        return await self._call(proto.status_action("validate"))

    async def validate_cancel(self) -> Json:
        """``validate cancel``."""
        return await self._call(proto.cancel_action("validate"), self.long_timeout)

    async def figures(self, job: JobKind = "characterize", log: Optional[str] = None) -> Json:
        """``figures``; see :meth:`Rig.figures`."""
        return await self._call(proto.figures(job, log), self.long_timeout)

    async def current_job(self) -> "Optional[AsyncJob]":
        """A handle on the daemon's current or last job; see :meth:`Rig.current_job`."""
        job = (await self.status()).get("job")
        if not isinstance(job, dict):
            return None
        return AsyncJob(self, job["kind"], job["log"], {"ok": True, "job": job})


class AsyncTables:
    """``tables`` (``rig.tables``); see :class:`~micropos.client.Tables`."""

    def __init__(self, rig: AsyncRig) -> None:
        self._rig = rig

    async def list(self) -> Json:
        """``tables list``."""
        return await self._rig._call({"cmd": "tables", "action": "list"})

    async def load(self, name: str) -> Json:
        """``tables load``."""
        return await self._rig._call({"cmd": "tables", "action": "load", "name": name})

    async def activate(self, name: Optional[str]) -> Json:
        """``tables activate``; ``None`` deactivates."""
        return await self._rig._call(proto.tables_activate(name))

    async def build(
        self,
        log: str,
        *,
        name: Optional[str] = None,
        kinds: Optional[Iterable[TableKind]] = None,
        activate: bool = False,
        timeout: Optional[float] = None,
    ) -> Json:
        """``tables build``."""
        req = proto.tables_build(log, name, kinds, activate)
        return await self._rig._call(req, self._rig._long(timeout))


class AsyncDrift:
    """``drift`` (``rig.drift``); see :class:`~micropos.client.Drift`."""

    def __init__(self, rig: AsyncRig) -> None:
        self._rig = rig

    async def show(self) -> Json:
        """``drift show``."""
        return await self._rig._call({"cmd": "drift", "action": "show"})

    async def set(
        self,
        method: Optional[DriftMethod] = None,
        *,
        every_s: Optional[float] = None,
        time_constant_s: Optional[float] = None,
    ) -> Json:
        """``drift set``; unset fields stay."""
        return await self._rig._call(proto.drift_set(method, every_s, time_constant_s))

    async def reset(self) -> Json:
        """``drift reset``."""
        return await self._rig._call({"cmd": "drift", "action": "reset"})

    async def measure(self, *, timeout: Optional[float] = None) -> Json:
        """``drift measure``."""
        req = {"cmd": "drift", "action": "measure"}
        return await self._rig._call(req, self._rig._long(timeout))


class AsyncJob:
    """A job in the daemon; see :class:`~micropos.Job`. ``await job.progress``
    reads its status now."""

    def __init__(self, rig: AsyncRig, kind: JobKind, log: str, started: Json) -> None:
        self._rig = rig
        self.kind: JobKind = kind
        self.log = log
        self.started = started

    @classmethod
    def _from_reply(cls: "Type[AsyncJob]", rig: AsyncRig, kind: JobKind, reply: Json) -> "AsyncJob":
        job = reply.get("job")
        if not isinstance(job, dict) or not isinstance(job.get("log"), str):
            raise ProtocolError(f"{kind} reply without job.log: {reply!r}", reply=reply)
        return cls(rig, kind, job["log"], reply)

    def __repr__(self) -> str:
        return f"AsyncJob({self.kind!r}, log={self.log!r})"

    async def status(self) -> Json:
        """The whole status reply of this job's command."""
        reply = await self._rig._call(proto.status_action(self.kind))
        proto.job_of(reply, self.kind, self.log)
        return reply

    @property
    def progress(self) -> Awaitable[JobProgress]:
        """``await job.progress``: the job's status object, read now."""
        return self._progress()

    async def _progress(self) -> JobProgress:
        return cast(JobProgress, (await self.status())["job"])

    async def wait(self, timeout: Optional[float] = None, poll_s: float = 1.0) -> Json:
        """Polls until the job ends; see :meth:`Job.wait`."""
        if poll_s <= 0:
            raise ValueError("poll_s must be positive")
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            reply = await self.status()
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
            await asyncio.sleep(pause)

    async def cancel(self) -> Json:
        """Cancels the job (after its current point or pose)."""
        await self.status()  # refuse to cancel someone else's job
        return await self._rig._call(proto.cancel_action(self.kind), self._rig.long_timeout)


class AsyncSubscription(AsyncIterator[Json]):
    """Events of a ``subscribe``; ``async for event in sub``. See
    :class:`~micropos.Subscription` for keepalive and errors."""

    def __init__(
        self,
        conn: _Connection,
        topics: List[str],
        pending: List[Json],
        *,
        reply_timeout: float,
        timeout: Optional[float],
        keepalive_s: float,
    ) -> None:
        self._conn = conn
        #: The topics the daemon confirmed.
        self.topics = topics
        self._pending = pending
        self._reply_timeout = reply_timeout
        self._timeout = timeout
        self._keepalive_s = keepalive_s
        self._ping_id = 0
        self._ping_sent: Optional[float] = None
        self._last_heard = time.monotonic()

    @classmethod
    async def _open(
        cls,
        path: str,
        topics: Optional[Iterable[Topic]],
        *,
        connect_timeout: float,
        timeout: Optional[float],
        keepalive_s: float,
    ) -> "AsyncSubscription":
        if keepalive_s <= 0:
            raise ValueError("keepalive_s must be positive")
        conn = await _Connection.open(path, connect_timeout)
        pending: List[Json] = []
        try:
            deadline = time.monotonic() + connect_timeout
            await conn.send({**proto.subscribe(topics), "id": "subscribe"}, deadline)
            while True:
                msg = await conn.read(deadline)
                if proto.is_event(msg):
                    pending.append(msg)
                    continue
                if msg.get("id") == "subscribe":
                    reply = proto.check_reply(msg)
                    break
                err = proto.unsolicited_error(msg)
                if err is not None:
                    raise err
        except BaseException:
            conn.close()
            raise
        return cls(
            conn,
            proto.topics_list(reply),
            pending,
            reply_timeout=connect_timeout,
            timeout=timeout,
            keepalive_s=keepalive_s,
        )

    async def __aenter__(self) -> "AsyncSubscription":
        return self

    async def __aexit__(self, *exc: Any) -> None:
        self.close()

    def __aiter__(self) -> "AsyncSubscription":
        return self

    async def __anext__(self) -> Json:
        if self._conn.closed and not self._pending:
            raise StopAsyncIteration
        return await self.next(self._timeout)

    def close(self) -> None:
        """Ends the subscription; iteration stops."""
        self._conn.close()

    async def next(self, timeout: Optional[float] = None) -> Json:
        """The next event; :class:`Timeout` if none within ``timeout`` s."""
        if self._pending:
            return self._pending.pop(0)
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            if self._ping_sent is not None:
                wake = self._ping_sent + self._reply_timeout
            else:
                wake = self._last_heard + self._keepalive_s
            if deadline is not None and deadline < wake:
                wake = deadline
            try:
                msg = await self._conn.read(wake)
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
                    await self._conn.send(
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
            self._ping_sent = None
