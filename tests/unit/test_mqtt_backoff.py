"""Reconnect backoff: exponential, capped, jittered; topics refuse ids that break MQTT."""

from __future__ import annotations

import random

import pytest

from hostd.publishing.mqtt import Backoff, MqttSetupError, Topics


def test_backoff_grows_exponentially_with_jitter_up_to_the_cap() -> None:
    backoff = Backoff(initial_s=0.5, maximum_s=30.0, factor=2.0)
    rng = random.Random(7)
    for attempt in range(12):
        ceiling = min(30.0, 0.5 * 2**attempt)
        delays = [backoff.delay(attempt, rng) for _ in range(50)]
        assert all(ceiling / 2 <= delay <= ceiling for delay in delays)
        assert len({round(delay, 6) for delay in delays}) > 40, "jittered, not fixed"
    assert backoff.delay(10_000, rng) <= 30.0  # no overflow after a long outage


def test_topics_follow_the_design() -> None:
    topics = Topics.for_printer("mk3")
    assert (topics.online, topics.status, topics.event, topics.cmd) == (
        "hostd/mk3/online", "hostd/mk3/status", "hostd/mk3/event", "hostd/mk3/cmd"
    )
    for bad in ("", "a/b", "a+", "#"):
        with pytest.raises(MqttSetupError):
            Topics.for_printer(bad)
