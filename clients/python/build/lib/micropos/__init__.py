"""Python client of ``microposd``, the micropos XY stage daemon.

Pure standard library. The blocking API is :class:`Rig`; the asyncio API is
:class:`AsyncRig`, method for method the same. Both speak the daemon's socket
protocol (docs/socket-protocol.md in the micropos repository) one command to
one method, return the daemon's replies as dictionaries, and raise one
exception class per protocol error code (:mod:`micropos.errors`).

>>> from micropos import Rig
>>> with Rig("/run/micropos/micropos.sock") as rig:      # doctest: +SKIP
...     rig.reference()
...     rig.move(x_um=2000, y_um=12000, mode="raw")
"""

from .aio import AsyncJob, AsyncRig, AsyncSubscription
from .client import DEFAULT_SOCKET, Drift, Job, Rig, Subscription, Tables
from .errors import *  # noqa: F401,F403 - every exception class is public API
from .errors import __all__ as _errors_all
from .types import JobProgress

__version__ = "0.1.0"

__all__ = [
    "Rig",
    "AsyncRig",
    "Job",
    "AsyncJob",
    "Subscription",
    "AsyncSubscription",
    "Tables",
    "Drift",
    "JobProgress",
    "DEFAULT_SOCKET",
    *_errors_all,
]
