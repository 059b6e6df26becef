"""Configuration: defaults, relative folders, and every bad key or value refused by name."""

from __future__ import annotations

from pathlib import Path

import pytest

from hostd.config import ConfigError, load_config


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "hostd.toml"
    path.write_text(text)
    return path


def test_embedded_default_matches_design(tmp_path: Path) -> None:
    config = load_config(None, cwd=tmp_path)
    assert config.jobs.folder == tmp_path / "jobs"
    assert config.state.folder == tmp_path / "var"
    assert config.jobs.settle_s == 1.0
    assert config.jobs.max_bytes == 200_000_000
    assert config.printer.port == "sim"
    assert config.printer.baud == 250000
    assert config.printer.bed == (220.0, 220.0, 250.0)
    assert config.simulator.time_scale == 1.0
    assert config.mqtt.enabled is False
    assert config.mqtt.keepalive == 30
    assert config.slicing.infill_density == 0.2


def test_full_file_is_read(tmp_path: Path) -> None:
    path = write(tmp_path, """
[jobs]
folder = "in"
settle_s = 0.5
max_bytes = 1000
[state]
folder = "/tmp/x-state"
[printer]
id = "mk3"
port = "/dev/ttyACM0"
baud = 115200
bed = [250, 210, 200]
[simulator]
time_scale = 0
baud = 0
[mqtt]
enabled = true
host = "broker"
port = 8883
username = "u"
password = "p"
tls = true
ca_file = "ca.pem"
allow_commands = true
homeassistant = true
keepalive = 10
[runner]
lookahead = 2
[slicing]
infill.density = 0.5
infill.field = "wave"
nozzle_temp = 215
""")
    config = load_config(path, cwd=tmp_path)
    assert config.jobs.folder == tmp_path / "in"
    assert config.state.folder == Path("/tmp/x-state")
    assert config.printer.bed == (250.0, 210.0, 200.0)
    assert config.printer.id == "mk3"
    assert config.simulator.baud == 0
    assert config.mqtt.tls
    assert config.mqtt.allow_commands
    assert config.mqtt.keepalive == 10
    assert config.runner.lookahead == 2
    assert config.slicing.infill_density == 0.5
    assert config.slicing.infill_field == "wave"
    assert config.slicing.nozzle_temp == 215.0


@pytest.mark.parametrize(
    ("text", "key"),
    [
        ("[jobz]\nfolder='x'", "jobz"),
        ("jobs = 3", "jobs"),
        ("[jobs]\nfolderr = 'x'", "jobs.folderr"),
        ("[jobs]\nfolder = 3", "jobs.folder"),
        ("[jobs]\nfolder = ''", "jobs.folder"),
        ("[jobs]\nsettle_s = -1", "jobs.settle_s"),
        ("[jobs]\nsettle_s = 'slow'", "jobs.settle_s"),
        ("[jobs]\nsettle_s = nan", "jobs.settle_s"),
        ("[jobs]\nmax_bytes = 0", "jobs.max_bytes"),
        ("[jobs]\nmax_bytes = 1.5", "jobs.max_bytes"),
        ("[state]\nfolder = []", "state.folder"),
        ("[state]\nmode = 1", "state.mode"),
        ("[printer]\nid = 'a/b'", "printer.id"),
        ("[printer]\nport = ''", "printer.port"),
        ("[printer]\nbaud = 12", "printer.baud"),
        ("[printer]\nbaud = true", "printer.baud"),
        ("[printer]\nbed = [220, 220]", "printer.bed"),
        ("[printer]\nbed = [220, 220, -5]", "printer.bed"),
        ("[printer]\nbed = [220, 'x', 5]", "printer.bed"),
        ("[simulator]\ntime_scale = -0.5", "simulator.time_scale"),
        ("[simulator]\nbaud = -1", "simulator.baud"),
        ("[simulator]\nfaults = 1", "simulator.faults"),
        ("[mqtt]\nenabled = 'yes'", "mqtt.enabled"),
        ("[mqtt]\nport = 70000", "mqtt.port"),
        ("[mqtt]\nhost = ''", "mqtt.host"),
        ("[mqtt]\ntls = 1", "mqtt.tls"),
        ("[mqtt]\nkeepalive = 1", "mqtt.keepalive"),
        ("[mqtt]\nallow_commands = 'true'", "mqtt.allow_commands"),
        ("[mqtt]\npasword = 'x'", "mqtt.pasword"),
        ("[runner]\nlookahead = 0", "runner.lookahead"),
        ("[slicing]\ninfill.density = 1.5", "slicing.infill.density"),
        ("[slicing]\ninfill.field = 'plaid'", "slicing.infill.field"),
        ("[slicing]\nlayer_hieght = 0.2", "slicing.layer_hieght"),
        ("[slicing]\nnozzle_temp = 'hot'", "slicing.nozzle_temp"),
    ],
)
def test_bad_values_are_refused_with_the_key_named(tmp_path: Path, text: str, key: str) -> None:
    with pytest.raises(ConfigError) as info:
        load_config(write(tmp_path, text), cwd=tmp_path)
    assert info.value.key == key
    assert str(info.value).startswith(f"{key}:")


def test_unparsable_and_missing_files(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(write(tmp_path, "[jobs\n"), cwd=tmp_path)
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(tmp_path / "absent.toml", cwd=tmp_path)


def test_hostd_run_refuses_a_bad_file_with_exit_2_and_the_key(tmp_path: Path) -> None:
    import subprocess
    import sys

    path = write(tmp_path, "[printer]\nbaud = 'fast'\n")
    result = subprocess.run(
        [sys.executable, "-c", "import sys; from hostd.app.cli import main; sys.exit(main())",
         "run", "--config", str(path)],
        capture_output=True, text=True, cwd=tmp_path, timeout=30,
    )
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        "hostd run: bad configuration: printer.baud: expected a whole number, got 'fast'"
    ]
