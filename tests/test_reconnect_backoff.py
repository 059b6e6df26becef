"""Reconnecting to the printer: the one jittered backoff policy, shared with the MQTT bridge."""

from __future__ import annotations

import itertools
import random

from drivers.backoff import Backoff
from hostd import mqtt
from hostd.daemon import RECONNECT


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
