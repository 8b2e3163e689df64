"""One blocking Unix-socket connection that reads whole lines with deadlines.

Why not ``socket.makefile()``: after a timeout its buffered reader is in an
undefined state (documented by Python), and every read here has a deadline.
This keeps its own byte buffer, so a timeout never loses or splits a line.
"""

import socket
import time
from typing import List, Optional

from ._protocol import MAX_LINE_BYTES, decode, encode
from .errors import ConnectionLost, DaemonUnreachable, ProtocolError, Timeout
from .types import Json


class Connection:
    """A connected socket plus a line buffer. Not thread-safe: the owner locks."""

    def __init__(self, path: str, timeout: float) -> None:
        self.path = path
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.settimeout(timeout)
        try:
            sock.connect(path)
        except socket.timeout:
            sock.close()
            raise DaemonUnreachable(
                f"connecting to {path} took longer than {timeout} s (daemon overloaded or stopped?)"
            ) from None
        except OSError as e:
            sock.close()
            raise DaemonUnreachable(
                f"cannot connect to the micropos daemon at {path}: {e.strerror or e}"
                " (is microposd running, is this its socket, may this user open it?)"
            ) from None
        self._sock: Optional[socket.socket] = sock
        self._buf = bytearray()
        self._lines: List[bytes] = []

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` ran (or the connection broke)."""
        return self._sock is None

    def close(self) -> None:
        """Closes the socket; idempotent."""
        sock, self._sock = self._sock, None
        if sock is not None:
            try:
                sock.close()
            except OSError:
                pass

    def send(self, req: Json, deadline: float) -> None:
        """Writes one request line (encoding errors raise before any byte)."""
        data = encode(req)
        sock = self._live()
        try:
            sock.settimeout(_remaining(deadline))
            sock.sendall(data)
        except socket.timeout:
            self.close()
            raise Timeout(f"the daemon at {self.path} did not accept a request in time") from None
        except OSError as e:
            self.close()
            raise ConnectionLost(f"connection to {self.path} lost while sending: {e}") from None

    def read(self, deadline: Optional[float]) -> Json:
        """The next line as an object; waits at most until ``deadline``
        (``time.monotonic()`` seconds; ``None`` waits without limit, for a
        caller that handles idleness itself)."""
        while not self._lines:
            sock = self._live()
            try:
                sock.settimeout(None if deadline is None else _remaining(deadline))
                chunk = sock.recv(65536)
            except socket.timeout:
                raise Timeout(f"no answer from the daemon at {self.path} in time") from None
            except OSError as e:
                self.close()
                raise ConnectionLost(f"connection to {self.path} lost: {e}") from None
            if not chunk:
                self.close()
                raise ConnectionLost(f"the daemon at {self.path} closed the connection")
            self._buf.extend(chunk)
            *complete, rest = bytes(self._buf).split(b"\n")
            self._lines.extend(l for l in complete if l.strip())
            self._buf = bytearray(rest)
            if len(self._buf) > MAX_LINE_BYTES:
                self.close()
                raise ProtocolError(f"a line from {self.path} exceeds {MAX_LINE_BYTES} bytes")
        return decode(self._lines.pop(0))

    def _live(self) -> socket.socket:
        if self._sock is None:
            raise ConnectionLost(f"the connection to {self.path} is closed")
        return self._sock


def _remaining(deadline: float) -> float:
    """Seconds left until ``deadline``; a tiny positive floor because
    ``settimeout(0)`` would switch the socket to non-blocking mode."""
    return max(deadline - time.monotonic(), 1e-3)
