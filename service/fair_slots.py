"""Fair slots: at most ``slots`` calls at a time, shared between users.

The GIS result endpoints (service/gis_process.py) compute in a few processes; each lane of them
is a :class:`FairSlots` of as many slots as it has processes, so a lane's process pool never
holds a waiting call of its own (its queue is first come, first served). A free slot goes to
the waiting user with the fewest calls running, then to the user served longest ago, then to
the oldest call: one user's burst of requests takes turns with another user's single one.
"""

from __future__ import annotations

import asyncio
import itertools
import threading
from collections import Counter
from dataclasses import dataclass, field


@dataclass
class _Waiter:
    owner: str
    seq: int
    loop: asyncio.AbstractEventLoop
    granted: asyncio.Future[None] = field(repr=False)


class FairSlots:
    """``slots`` places shared fairly between owners (see module docstring); thread-safe, usable
    from several event loops."""

    def __init__(self, slots: int) -> None:
        if slots < 1:
            raise ValueError("at least one slot")
        self.slots = slots
        self._lock = threading.Lock()
        self._running: Counter[str] = Counter()
        self._last_served: dict[str, int] = {}
        self._waiting: list[_Waiter] = []
        self._seq = itertools.count()

    def running(self) -> int:
        """Calls holding a slot now."""
        with self._lock:
            return sum(self._running.values())

    def waiting(self) -> int:
        """Calls waiting for a slot now."""
        with self._lock:
            return len(self._waiting)

    def _grant(self, owner: str) -> None:  # under the lock
        self._running[owner] += 1
        self._last_served[owner] = next(self._seq)

    async def acquire(self, owner: str) -> None:
        """Wait for a slot for ``owner`` (release it with :meth:`release`)."""
        loop = asyncio.get_running_loop()
        with self._lock:
            if not self._waiting and sum(self._running.values()) < self.slots:
                self._grant(owner)
                return
            waiter = _Waiter(owner, next(self._seq), loop, loop.create_future())
            self._waiting.append(waiter)
        try:
            await waiter.granted
        except asyncio.CancelledError:
            with self._lock:
                still_waiting = waiter in self._waiting
                if still_waiting:
                    self._waiting.remove(waiter)
            if not still_waiting:  # granted as the wait was cancelled: hand the slot on
                self.release(owner)
            raise

    def release(self, owner: str) -> None:
        """Give ``owner``'s slot to the next waiting call (the fair order)."""
        with self._lock:
            self._running[owner] -= 1
            if self._running[owner] <= 0:
                del self._running[owner]
            if not self._waiting:
                return
            nxt = min(
                self._waiting,
                key=lambda w: (self._running[w.owner], self._last_served.get(w.owner, -1), w.seq),
            )
            self._waiting.remove(nxt)
            self._grant(nxt.owner)
        nxt.loop.call_soon_threadsafe(_wake, nxt.granted)


def _wake(granted: asyncio.Future[None]) -> None:
    if not granted.done():
        granted.set_result(None)
