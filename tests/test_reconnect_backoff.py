"""Reconnecting to the printer: delays that double up to a cap, each spread at random."""

from __future__ import annotations

import random

from hostd.daemon import RECONNECT_FIRST_S, RECONNECT_MAX_S, backoff


def test_delays_double_up_to_the_cap_and_are_spread_by_a_quarter() -> None:
    rng = random.Random(3)
    delay, waits, delays = RECONNECT_FIRST_S, [], []
    for _attempt in range(10):
        wait, following = backoff(delay, rng)
        assert 0.75 * delay <= wait <= 1.25 * delay
        waits.append(wait)
        delays.append(delay)
        delay = following
    assert delays[:6] == [1.0, 2.0, 4.0, 8.0, 16.0, 30.0]
    assert set(delays[5:]) == {RECONNECT_MAX_S}
    # two hosts that lost the same link do not retry in step
    other = [backoff(d, random.Random(4))[0] for d in delays]
    assert all(abs(a - b) > 1e-6 for a, b in zip(waits, other, strict=True))
