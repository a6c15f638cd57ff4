"""The fair slots the GIS lanes share (service/fair_slots.py): a free slot goes to the waiting
user with the fewest calls running, then to the one served longest ago, then the oldest call;
a cancelled wait gives its place (or a slot granted meanwhile) on."""

from __future__ import annotations

import asyncio
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Coroutine

import pytest

from service.fair_slots import FairSlots


def _run(scenario: Coroutine[Any, Any, Any]) -> Any:
    """``asyncio.run`` in a thread of its own: the browser tests' Playwright (its sync API) keeps an
    event loop running in the test process's main thread for the whole session."""
    with ThreadPoolExecutor(1) as pool:
        return pool.submit(asyncio.run, scenario).result()


async def _settle() -> None:
    for _ in range(5):
        await asyncio.sleep(0)


def _order(slots: FairSlots, order: list[str], owner: str, tag: str) -> asyncio.Task[None]:
    async def go() -> None:
        await slots.acquire(owner)
        order.append(tag)

    return asyncio.ensure_future(go())


def test_a_waiting_user_goes_before_a_users_burst() -> None:
    async def scenario() -> list[str]:
        slots, order = FairSlots(1), []
        await slots.acquire("a")  # a's long request runs
        tasks = [_order(slots, order, "a", f"a{k}") for k in range(3)]
        await _settle()
        tasks.append(_order(slots, order, "b", "b0"))  # b arrives after a's burst
        await _settle()
        for _ in range(4):
            slots.release(order[-1][0] if order else "a")
            await _settle()
        await asyncio.gather(*tasks)
        return order

    assert _run(scenario()) == ["b0", "a0", "a1", "a2"]


def test_users_take_turns_when_both_wait() -> None:
    async def scenario() -> list[str]:
        slots, order = FairSlots(1), []
        await slots.acquire("c")
        tasks = [_order(slots, order, o, f"{o}{k}") for k in range(2) for o in ("a",)]
        tasks += [_order(slots, order, "b", f"b{k}") for k in range(2)]
        await _settle()
        slots.release("c")
        for _ in range(4):
            await _settle()
            slots.release(order[-1][0])
        await asyncio.gather(*tasks)
        return order

    assert _run(scenario()) == ["a0", "b0", "a1", "b1"]


def test_no_more_than_the_slots_run() -> None:
    async def scenario() -> tuple[int, int]:
        slots = FairSlots(2)
        tasks = [asyncio.ensure_future(slots.acquire(o)) for o in "abc"]
        await _settle()
        seen = (slots.running(), slots.waiting())
        slots.release("a")
        await _settle()
        await asyncio.gather(*tasks)
        return seen

    assert _run(scenario()) == (2, 1)


def test_a_cancelled_wait_gives_its_place_on() -> None:
    async def scenario() -> list[str]:
        slots, order = FairSlots(1), []
        await slots.acquire("a")
        gone = _order(slots, order, "b", "b0")
        kept = _order(slots, order, "c", "c0")
        await _settle()
        gone.cancel()
        await _settle()
        slots.release("a")
        await _settle()
        await kept
        with pytest.raises(asyncio.CancelledError):
            await gone
        return order

    assert _run(scenario()) == ["c0"]


def test_a_slot_granted_to_a_cancelled_wait_is_handed_on() -> None:
    async def scenario() -> tuple[list[str], int]:
        slots, order = FairSlots(1), []
        await slots.acquire("a")
        gone = _order(slots, order, "b", "b0")
        kept = _order(slots, order, "c", "c0")
        await _settle()
        slots.release("a")  # b is granted the slot ...
        gone.cancel()  # ... and cancelled before it runs
        await _settle()
        await kept
        with pytest.raises(asyncio.CancelledError):
            await gone
        return order, slots.running()

    assert _run(scenario()) == (["c0"], 1)
