"""Link settings for real boards: ``[printer.link]`` checked like every key, firmware defaults."""

from __future__ import annotations

import asyncio
import logging
from pathlib import Path

import pytest
from support.linkrun import arc_job as job
from support.streaming import FAST, job_lines, sim_config, stream_job

from drivers.link.config import LinkSettingError, StreamerConfig
from drivers.link.profile import profile_for, tuned
from drivers.sim.printer import SimulatedPrinter
from hostd.config import ConfigError, config_from_mapping


def _config(link: dict) -> StreamerConfig:
    return config_from_mapping({"printer": {"port": "sim", "link": link}}, Path.cwd()).printer.link


def test_every_link_setting_is_reachable_from_printer_link():
    values = {
        "rx_buffer": 255, "bufsize": 8, "learn_bufsize": False, "history": 500,
        "start_timeout_s": 3, "connect_timeout_s": 20.0, "probe_after_s": 2.5,
        "probe_retries": 5, "busy_silence_s": 6.0, "long_command_timeout_s": 1200,
        "temperature_interval_s": 0,
        "renumber_at": 50_000, "park_gcode": ["G91", "G1 Z5", "G90"], "unpark_gcode": [],
        "ok_after_resend": False, "resync_quiet_s": 0.5, "renumber_retry_s": 2.0,
        "reconnect_attempts": 3, "reconnect_delay_s": 0.5, "firmware_defaults": False,
        "read_motion": False,
    }
    assert set(values) == set(StreamerConfig.setting_names())
    link = _config(values)
    for key, value in values.items():
        expected = tuple(value) if isinstance(value, list) else value
        assert getattr(link, key) == expected, key
    assert link.explicit == frozenset(values)
    assert _config({}) == StreamerConfig()


@pytest.mark.parametrize(("link", "key", "reason"), [
    ({"rx_bufer": 127}, "printer.link.rx_bufer", "unknown key"),
    ({"bufsize": 0}, "printer.link.bufsize", "1..1024"),
    ({"bufsize": 4.5}, "printer.link.bufsize", "whole number"),
    ({"ok_after_resend": "no"}, "printer.link.ok_after_resend", "true or false"),
    ({"probe_after_s": 0}, "printer.link.probe_after_s", "> 0"),
    ({"probe_after_s": float("nan")}, "printer.link.probe_after_s", "finite"),
    ({"park_gcode": "G91"}, "printer.link.park_gcode", "list of G-code lines"),
    ({"renumber_at": 10}, "printer.link.renumber_at", "at least 1000"),
])
def test_bad_link_settings_are_refused_with_the_key_named(link, key, reason):
    with pytest.raises(ConfigError) as caught:
        _config(link)
    assert caught.value.key == key
    assert reason in caught.value.reason


def test_a_link_table_that_is_not_a_table_is_refused():
    with pytest.raises(ConfigError, match=r"printer\.link"):
        config_from_mapping({"printer": {"link": 3}}, Path.cwd())
    with pytest.raises(LinkSettingError, match="history"):
        StreamerConfig(history=10)


@pytest.mark.parametrize(("banner", "caps", "name", "expect"), [
    ("Marlin 2.1.2.1 (Github)", {}, "marlin-2.1", {"ok_after_resend": True, "rx_buffer": 127}),
    ("Marlin bugfix-2.1.x", {}, "marlin-2.1", {"bufsize": 4}),
    ("Marlin 2.0.9.3 (Github)", {}, "marlin-2.0", {"ok_after_resend": True}),
    ("Prusa-Firmware 3.13.2 based on Marlin", {}, "prusa", {"long_command_timeout_s": 1800.0}),
    ("Marlin 2.1.2", {"SERIAL_XON_XOFF": "1"}, "marlin-2.1", {"rx_buffer": 1023}),
    ("Smoothieware", {}, "generic", {"rx_buffer": 127}),
])
def test_the_firmware_and_its_capabilities_choose_defaults(banner, caps, name, expect):
    profile = profile_for(banner, caps)
    assert profile.name == name
    config, _ = tuned(StreamerConfig(), profile)
    for key, value in expect.items():
        assert getattr(config, key) == value


def test_settings_the_user_chose_are_never_overridden():
    profile = profile_for("Marlin 2.1.2", {"SERIAL_XON_XOFF": "1"})
    chosen = StreamerConfig.from_mapping({"rx_buffer": 200})
    assert tuned(chosen, profile)[0].rx_buffer == 200
    assert tuned(StreamerConfig(rx_buffer=300), profile)[0].rx_buffer == 300
    off = StreamerConfig.from_mapping({"firmware_defaults": False})
    assert tuned(off, profile) == (off, {})


def test_the_profile_is_chosen_and_logged_at_connect(caplog):
    caplog.set_level(logging.INFO, logger="drivers.link")
    lines = job(50)
    with SimulatedPrinter(sim_config()) as sim:
        link = asyncio.run(stream_job(sim, lines, FAST))
        executed = list(sim.executed)
    assert job_lines(executed) == lines
    assert link.profile is not None
    assert link.profile.name == "marlin-2.1"
    assert any("marlin-2.1" in record.getMessage() for record in caplog.records)
