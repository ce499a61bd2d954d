"""Who may write a sweep run now (its lease), and the record of every attempt at it.

A run may be attempted more than once: Ray retries a task whose worker or node died, and a
driver started again submits the unfinished runs anew. A node that was only cut off (a
network split) may come back and go on with its stale attempt while the retry runs
elsewhere. The lease fences it off: each attempt takes the lease when it starts (the newest
attempt wins, since a retry only exists because the older one was given up for dead), and
checks that it still holds it before each file it writes (checkpoint, weights, scores,
row). A stale holder finds another token there and stops with :class:`LeaseLost`.

Files, in the sweep folder every node sees::

    OUT/state/NAME[/seed-S]/lease.json                      the holder of the run now
    OUT/state/NAME[/seed-S]/attempt-STAGE-TIME-TOKEN.json   one per attempt: node, start,
                                                            resumed epoch, end, outcome
    OUT/state/NAME[/seed-S]/train-TIME-PID.log              a train task's output

The check and the write that follows it are not one atomic step (a shared filesystem
offers no compare-and-swap), so a holder cut off in the milliseconds between them could
still land one file; the window is far shorter than the seconds it takes a cluster to give
a node up, and the file would be a row of the same config.
"""

from __future__ import annotations

import json
import os
import secrets
import socket
import time
from dataclasses import dataclass, field
from pathlib import Path

from slimseg.errors import SlimsegError
from slimseg.utils.atomic import write_json

LEASE = "lease.json"
# Set by the ray backend's task: when it started the run's process (``time.time()``), so an
# attempt record shows how long the process took to start before it took the lease.
TASK_STARTED_ENV = "SLIMSEG_TASK_STARTED"


class LeaseLost(SlimsegError):
    """Another attempt took the run over: this one must stop writing."""


def state_dir(out: Path, label: str) -> Path:
    """The state folder of run ``label`` (``NAME`` or ``NAME/seed-S``) of sweep ``out``."""
    return Path(out) / "state" / label


def node_name() -> str:
    """This machine as progress lines name it: the host name, unless the caller set
    ``SLIMSEG_NODE`` (the ray backend: host and Ray node id, several nodes may share a host)."""
    return os.environ.get("SLIMSEG_NODE") or socket.gethostname()


@dataclass
class Lease:
    """An attempt's hold on a run; ``record`` is its attempt file's content."""

    state: Path
    token: str
    record: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        """``STAGE-TIME-TOKEN``: this attempt's files are named after it."""
        stamp = time.strftime("%Y%m%dT%H%M%S", time.gmtime(self.record["started"]))
        return f"{self.record['stage']}-{stamp}-{self.token}"

    @property
    def attempt_path(self) -> Path:
        return self.state / f"attempt-{self.name}.json"

    def holder(self) -> dict | None:
        """The lease file's content now (None when there is none)."""
        path = self.state / LEASE
        try:
            return json.loads(path.read_text())
        except (FileNotFoundError, json.JSONDecodeError):
            return None

    def check(self, before: str) -> None:
        """Raise :class:`LeaseLost` unless this attempt still holds the run; ``before``
        names the write it guards (for the message)."""
        now = self.holder()
        if now is None or now.get("token") != self.token:
            other = "nobody" if now is None else f"{now.get('node')} (pid {now.get('pid')})"
            raise LeaseLost(
                f"{self.state.name}: this attempt ({self.record['node']}, pid "
                f"{self.record['pid']}) no longer holds the run, {other} does; it stops "
                f"before {before} and leaves the run to the newer attempt"
            )

    def update(self, **fields: object) -> None:
        """Add ``fields`` to the attempt's record (rewritten atomically)."""
        self.record |= fields
        write_json(self.attempt_path, self.record, indent=1)

    def finish(self, outcome: str) -> None:
        """Close the attempt's record: ``outcome`` is done, lease lost or failed."""
        self.update(finished=time.time(), outcome=outcome)


def acquire_lease(state: Path, stage: str, **record: object) -> Lease:
    """Take run ``state``'s lease for a new attempt at ``stage`` (``train`` or ``measure``)
    and write its attempt record; ``record`` adds fields to it (the resumed epoch, ...)."""
    token = secrets.token_hex(6)
    lease = Lease(Path(state), token)
    lease.record = {
        "token": token,
        "stage": stage,
        "node": node_name(),
        "host": socket.gethostname(),
        "pid": os.getpid(),
        "started": time.time(),
        **record,
    }
    if os.environ.get(TASK_STARTED_ENV):
        lease.record["task_started"] = float(os.environ[TASK_STARTED_ENV])
    write_json(lease.state / LEASE, {k: lease.record[k] for k in ("token", "node", "pid")})
    lease.update()
    return lease


def read_attempts(state: Path) -> list[dict]:
    """Every attempt recorded for a run, oldest first (an attempt cut off by a dead
    process or node has no ``finished``)."""
    records = []
    for path in Path(state).glob("attempt-*.json"):
        try:
            records.append(json.loads(path.read_text()))
        except (OSError, json.JSONDecodeError):
            continue  # removed or replaced while listing: read again on the next poll
    return sorted(records, key=lambda r: r.get("started", 0.0))
