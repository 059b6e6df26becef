"""Reconnecting: the one jittered backoff policy (printer link, MQTT) and the one reconnect loop."""

from __future__ import annotations

import asyncio
import itertools
import random

import pytest

from drivers.link.backoff import Backoff, reconnect
from hostd.app.daemon import RECONNECT
from hostd.publishing import mqtt


def test_printer_delays_double_from_one_second_up_to_the_cap_each_drawn_at_random() -> None:
    rng = random.Random(3)
    waits = list(itertools.islice(RECONNECT.delays(rng), 10))
    ceilings = [min(30.0, 1.0 * 2**k) for k in range(10)]
    assert ceilings[:6] == [1.0, 2.0, 4.0, 8.0, 16.0, 30.0]
    assert all(c / 2 <= w <= c for w, c in zip(waits, ceilings, strict=True))
    # two hosts that lost the same link do not retry in step
    other = list(itertools.islice(RECONNECT.delays(random.Random(4)), 10))
    assert all(abs(a - b) > 1e-6 for a, b in zip(waits, other, strict=True))


def test_the_mqtt_bridge_and_the_printer_link_share_one_policy() -> None:
    assert mqtt.Backoff is Backoff
    assert isinstance(RECONNECT, Backoff)


def test_reconnect_tries_until_an_attempt_succeeds_and_gives_up_after_attempts() -> None:
    policy = Backoff(initial_s=0.001, maximum_s=0.004)
    tries: list[int] = []
    told: list[tuple[str, float]] = []

    async def attempt() -> str:
        tries.append(len(tries))
        if len(tries) < 4:
            raise OSError(f"port gone ({len(tries)})")
        return "open"

    def failed(error: Exception, wait: float) -> None:
        told.append((str(error), wait))

    assert asyncio.run(reconnect(attempt, policy, errors=(OSError,), failed=failed)) == "open"
    assert len(tries) == 4
    assert [text for text, _ in told] == ["port gone (1)", "port gone (2)", "port gone (3)"]
    ceilings = [0.001, 0.002, 0.004]  # the policy's, attempt after attempt
    assert all(c / 2 <= wait <= c for (_, wait), c in zip(told, ceilings, strict=True))

    tries.clear()
    with pytest.raises(OSError, match=r"port gone \(2\)"):
        asyncio.run(reconnect(attempt, policy, errors=(OSError,), attempts=2, wait_first=True))
    assert len(tries) == 2
    with pytest.raises(ValueError, match="not a reconnect"):  # other errors pass through

        async def broken() -> None:
            raise ValueError("not a reconnect matter")

        asyncio.run(reconnect(broken, policy, errors=(OSError,)))
