"""The layer window shared by the daemon, `hostd print` and `hostd slice`: bounded, in order."""

from __future__ import annotations

import asyncio
import concurrent.futures
import threading

import pytest

from slicer.pipeline import Deferred, LayerWindow, in_thread


class Maker:
    """Makes layer ``i`` as ``[i] * width(i)`` on a thread pool, recording what was submitted."""

    def __init__(self, pool: concurrent.futures.Executor, width=lambda i: 2) -> None:
        self.pool = pool
        self.width = width
        self.submitted: list[int] = []
        self.gate = threading.Event()
        self.gate.set()

    def submit(self, index: int) -> concurrent.futures.Future[list[int]]:
        self.submitted.append(index)
        return self.pool.submit(self.make, index)

    def make(self, index: int) -> list[int]:
        self.gate.wait(10)
        return [index] * self.width(index)


def test_layers_come_in_order_never_more_than_the_depth_ahead() -> None:
    with concurrent.futures.ThreadPoolExecutor(3) as pool:
        maker = Maker(pool)
        window = LayerWindow(maker.submit, 20, depth=3, first=5)
        taken = []
        for layer in window:
            taken.append(layer[0])
            # what was submitted and not yet taken never exceeds the depth
            assert len(maker.submitted) - len(taken) <= 3
    assert taken == list(range(5, 20))
    assert maker.submitted == list(range(5, 20))


def test_alone_makes_one_layer_at_a_time_until_one_is_worth_it() -> None:
    with concurrent.futures.ThreadPoolExecutor(3) as pool:
        maker = Maker(pool, width=lambda i: 1 if i < 2 else 2)  # layers 0, 1: empty
        maker.gate.clear()
        window = LayerWindow(maker.submit, 10, depth=4, alone=True, worth=lambda r: len(r) > 1)
        assert maker.submitted == [0]  # alone: nothing else while layer 0 is made
        maker.gate.set()
        assert [window.take(i)[0] for i in range(3)] == [0, 1, 2]
        assert window.next_unsliced == 3 + 4  # layer 2 was worth it: the full window since


def test_async_take_checks_the_order_and_close_drops_pending_work() -> None:
    async def main() -> None:
        with concurrent.futures.ThreadPoolExecutor(2) as pool:
            maker = Maker(pool)
            window = LayerWindow(maker.submit, 10, depth=2)
            assert await window.take_async(0) == [0, 0]
            with pytest.raises(RuntimeError, match="layer 3 asked for, layer 1 is next"):
                await window.take_async(3)
            window.close()
            with pytest.raises(IndexError):
                window.take()
            assert maker.submitted == [0, 1, 2]

    asyncio.run(main())


def test_the_in_thread_engine_makes_each_layer_when_taken_by_the_taker() -> None:
    made: list[tuple[int, int]] = []

    def make(index: int) -> list[int]:
        made.append((index, threading.get_ident()))
        return [index]

    window = LayerWindow(in_thread(make), 5, depth=2)
    assert made == []  # submitted, not made: nothing runs beside the consumer
    assert window.take(0) == [0]
    assert made == [(0, threading.get_ident())]
    assert [layer[0] for layer in window] == [1, 2, 3, 4]
    assert made == [(i, threading.get_ident()) for i in range(5)]


def test_a_pending_layer_cancelled_is_never_made_and_its_error_is_raised() -> None:
    calls: list[int] = []

    def make(index: int) -> list[int]:
        calls.append(index)
        if index == 1:
            raise ValueError("layer 1 cannot be made")
        return [index]

    window = LayerWindow(in_thread(make), 4, depth=3)
    assert window.take() == [0]
    with pytest.raises(ValueError, match="layer 1 cannot be made"):
        window.take()
    window.close()  # layers 2 and 3 were submitted, never made
    assert calls == [0, 1]
    calls.clear()
    deferred = Deferred(lambda: calls.append(9) or 9)
    assert deferred.cancel()
    assert deferred.cancelled()
    with pytest.raises(concurrent.futures.CancelledError):
        deferred.result()
    assert calls == []  # cancelled before anyone asked: never made


def test_a_deferred_layer_is_made_once_by_the_first_thread_that_asks() -> None:
    calls: list[int] = []
    begun, gate = threading.Event(), threading.Event()

    def make() -> int:
        calls.append(threading.get_ident())
        begun.set()
        gate.wait(10)
        return 7

    deferred = Deferred(make)
    results: list[int] = []
    asker = threading.Thread(target=lambda: results.append(deferred.result()))
    asker.start()
    assert begun.wait(10)  # the other thread began making it
    assert not deferred.cancel()  # begun: runs to its end
    gate.set()
    assert deferred.result(10) == 7  # waits for the other thread's making
    asker.join(10)
    assert results == [7]
    assert len(calls) == 1


def test_take_async_refuses_layers_made_by_the_taker() -> None:
    window = LayerWindow(in_thread(lambda i: [i]), 3, depth=1)
    with pytest.raises(TypeError, match="made elsewhere"):
        asyncio.run(window.take_async(0))
