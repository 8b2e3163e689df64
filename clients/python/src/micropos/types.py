"""Type names for the protocol's keywords and the job status object.

Why ``Literal`` aliases rather than enums: the protocol's values are plain
strings on the wire and in the docs (``mode="compensated"``); a script writes
them as such, and a type checker still catches ``mode="compensate"``. Replies
stay plain dictionaries, exactly as the daemon sent them
(docs/socket-protocol.md documents every field), so a field added by a newer
daemon reaches the script without a client upgrade.
"""

from typing import Any, Dict, Literal, Optional, TypedDict

__all__ = [
    "Json",
    "MoveMode",
    "Axes",
    "Topic",
    "ValidateTest",
    "ValidateMode",
    "TableKind",
    "CharacterizePlan",
    "GridApproach",
    "GridOrder",
    "DriftMethod",
    "JobKind",
    "JobProgress",
]

#: A reply or event object as received.
Json = Dict[str, Any]

#: How a move reaches its target.
MoveMode = Literal["raw", "compensated", "closed_loop"]
#: Which axes (``reference``, ``characterize``).
Axes = Literal["x", "y", "xy"]
#: Event topics of ``subscribe``.
Topic = Literal["position", "job", "fault", "drift"]
#: Trajectories of ``validate``.
ValidateTest = Literal["square", "random", "both"]
#: Modes of ``validate``.
ValidateMode = Literal["raw", "table", "model", "closed_loop"]
#: Table kinds of ``tables build``.
TableKind = Literal["paper", "model", "grid"]
#: Live drift correction methods.
DriftMethod = Literal["off", "static", "adaptive"]
#: Job kinds.
JobKind = Literal["characterize", "validate"]

#: How a characterization measures: stop and measure per point, or on the
#: fly at constant velocity (the camera delay estimated from the data).
CharacterizeMode = Literal["step", "sweep"]
CharacterizePlan = Literal["lines", "grid"]
#: How a grid plan reaches its nodes: from below on both axes (default), or
#: both ways (a map per arrival direction).
GridApproach = Literal["below", "both"]
#: The order of a grid plan's nodes: raster (default) or serpentine (needs
#: ``approach="both"``).
GridOrder = Literal["raster", "serpentine"]


class JobProgress(TypedDict, total=False):
    """A job's status object (``status.job``, ``characterize status``, ``job``
    events)."""

    kind: str
    log: str
    #: ``running``, ``done``, ``cancelled``, ``stopped`` or ``failed``.
    state: str
    #: Points (poses) measured so far.
    done: int
    #: Points (poses) in the plan.
    total: int
    #: Estimated remaining rig time, s (``None`` until known and once ended).
    eta_s: Optional[float]
    #: Why it failed or stopped.
    error: Optional[str]
    #: Operations retried after transient faults in this run of the job.
    retries: int
    #: A finished sweep characterization's findings (``camera_delay_s``,
    #: ``camera_delay_residual_um``, ``frames``, ``pos_samples``,
    #: ``records``, ``duration_s``); ``None`` for other jobs.
    result: Optional[Json]
