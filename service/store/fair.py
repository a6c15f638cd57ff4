"""Which accepted job a free worker takes next: the fair-share policy (docs/how-to/lab-server.md "Fair sharing").

The claim order is a key per waiting (owner, lane) head, smallest first:

1. **cap**: while more than one user has jobs waiting, a user already running
   ``max_running`` jobs (their own limit, else ``PBA_MAX_RUNNING_PER_USER``; 0 = no cap) comes
   after every user below their cap. With a single user waiting nobody is capped, so an
   otherwise idle server always runs the work it has;
2. **small-job lane**: jobs marked small at submission (by their cost, service.lanes:
   adjustments of at most ``PBA_SMALL_JOB_OBSERVATIONS`` observations, never a matching) come
   before the others, so a small job waits at most for the first running job to end;
3. **weighted share**: the user whose running jobs count for least per unit of weight
   (``users.weight``, default 1) comes first; a running job counts for its ``share``, what it
   costs in small jobs' worth (service.lanes.share_of: observations for adjustments, pixels
   for matchings; at least 1);
4. **least recent use**: among equals, the user whose last job started longest ago;
5. **age**: then the oldest job (creation time, then id).

The function is pure (no database); :meth:`service.store.sql.SqlStore.claim_next` gathers its
inputs in the claiming transaction.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from datetime import datetime, timezone

NEVER = datetime.min.replace(tzinfo=timezone.utc)


@dataclass(frozen=True)
class Head:
    """The oldest waiting job of one owner in one lane (``small`` True: the small-job lane)."""

    owner: str
    small: bool
    created: datetime


@dataclass(frozen=True)
class OwnerLoad:
    """What the policy knows of a user: running jobs now and their shares summed (None: one
    per job), weight, cap, last job start."""

    running: int = 0
    running_share: float | None = None
    weight: float = 1.0
    max_running: int = 0
    last_started: datetime | None = None


def order_key(
    head: Head, load: OwnerLoad, contended: bool
) -> tuple[bool, bool, float, datetime, datetime]:
    """The sort key of ``head`` (smaller runs first); ``contended``: several users wait."""
    capped = contended and load.max_running > 0 and load.running >= load.max_running
    counted = load.running if load.running_share is None else load.running_share
    share = counted / load.weight if load.weight > 0 else float("inf")
    return (capped, not head.small, share, load.last_started or NEVER, head.created)


def pick(heads: list[Head], loads: dict[str, OwnerLoad]) -> Head | None:
    """The head a free worker should take next, or None when nothing waits."""
    if not heads:
        return None
    contended = len({h.owner for h in heads}) > 1
    return min(heads, key=lambda h: order_key(h, loads.get(h.owner, OwnerLoad()), contended))


@dataclass(frozen=True)
class Waiting:
    """An accepted job as the policy sees it."""

    id: str
    owner: str
    small: bool
    created: datetime
    share: float = 1.0


def queue_order(waiting: list[Waiting], loads: dict[str, OwnerLoad]) -> list[str]:
    """The ids of ``waiting`` in the order free workers would claim them if no running job
    ended meanwhile (each claim counts as one more running job of its user, started now)."""
    loads = dict(loads)
    queues: dict[tuple[str, bool], list[Waiting]] = {}
    for w in sorted(waiting, key=lambda w: (w.created, w.id)):
        queues.setdefault((w.owner, w.small), []).append(w)
    now = datetime.now(timezone.utc)
    order: list[str] = []
    while queues:
        heads = [Head(o, sm, q[0].created) for (o, sm), q in queues.items()]
        head = pick(heads, loads)
        assert head is not None
        q = queues[(head.owner, head.small)]
        job = q.pop(0)
        order.append(job.id)
        if not q:
            del queues[(head.owner, head.small)]
        load = loads.get(head.owner, OwnerLoad())
        counted = load.running if load.running_share is None else load.running_share
        loads[head.owner] = replace(
            load, running=load.running + 1, running_share=counted + job.share, last_started=now
        )
    return order
