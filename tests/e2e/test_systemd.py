"""The systemd files: required directives, `systemd-analyze verify`, sysusers, tmpfiles, install."""

from __future__ import annotations

import os
import shlex
import shutil
import stat
import subprocess
import sys
from pathlib import Path, PurePosixPath

import pytest

from hostd.app.cli import build_parser
from hostd.config import load_config

SYSTEMD = Path(__file__).resolve().parents[2] / "systemd"
UNITS = ("hostd.service", "hostd@.service")


def parse_unit(path: Path) -> dict[str, dict[str, list[str]]]:
    """Sections of a unit file, each key with all its values (keys may repeat)."""
    sections: dict[str, dict[str, list[str]]] = {}
    current: dict[str, list[str]] | None = None
    for raw in path.read_text().splitlines():
        line = raw.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("[") and line.endswith("]"):
            current = sections.setdefault(line[1:-1], {})
            continue
        assert current is not None, f"{path.name}: {line!r} outside a section"
        key, sep, value = line.partition("=")
        assert sep, f"{path.name}: not a key=value line: {line!r}"
        current.setdefault(key.strip(), []).append(value.strip())
    return sections


def one(service: dict[str, list[str]], key: str) -> str:
    values = service.get(key, [])
    assert len(values) == 1, f"{key} must be set exactly once, got {values}"
    return values[0]


@pytest.mark.parametrize("name", UNITS)
def test_unit_has_every_required_directive(name: str) -> None:
    unit = parse_unit(SYSTEMD / name)
    service = unit["Service"]
    instance = "/%i" if "@" in name else ""
    config = "/etc/hostd/%i.toml" if instance else "/etc/hostd/hostd.toml"
    assert one(service, "Type") == "notify"
    assert one(service, "ExecStart") == f"/usr/local/bin/hostd run --config {config}"
    assert int(one(service, "WatchdogSec")) >= 10
    assert one(service, "Restart") == "on-failure"
    assert one(service, "User") == "hostd"
    assert one(service, "Group") == "hostd"
    assert "dialout" in one(service, "SupplementaryGroups").split()
    assert one(service, "StateDirectory") == f"hostd{instance}"
    assert one(service, "WorkingDirectory") == f"/var/lib/hostd{instance}"
    for key, value in [("NoNewPrivileges", "yes"), ("ProtectSystem", "strict"),
                       ("ProtectHome", "yes"), ("PrivateTmp", "yes"),
                       ("KillSignal", "SIGTERM")]:
        assert one(service, key) == value, key
    assert int(one(service, "TimeoutStopSec")) > 0
    assert f"/var/lib/hostd{instance}" in service["ReadWritePaths"]
    devices = set(service["DeviceAllow"])
    assert {"char-ttyUSB rw", "char-ttyACM rw", "/dev/ptmx rw", "char-pts rw"} <= devices
    assert one(service, "RestrictAddressFamilies").split() == ["AF_UNIX", "AF_INET", "AF_INET6"]
    # these would hide the serial device or forbid the pseudo-terminal of the simulator
    assert service.get("PrivateDevices", ["no"]) == ["no"]
    assert one(service, "CapabilityBoundingSet") == ""
    assert unit["Install"]["WantedBy"] == ["multi-user.target"]


@pytest.mark.parametrize("name", UNITS)
def test_exec_start_is_a_valid_hostd_command_line(name: str) -> None:
    service = parse_unit(SYSTEMD / name)["Service"]
    argv = shlex.split(one(service, "ExecStart"))
    args = build_parser().parse_args(argv[1:])
    assert args.command == "run"
    assert args.config.startswith("/etc/hostd/")


def test_the_template_differs_from_the_single_unit_only_by_instance() -> None:
    single = parse_unit(SYSTEMD / "hostd.service")
    template = parse_unit(SYSTEMD / "hostd@.service")
    assert single.keys() == template.keys()
    for section in single:
        assert single[section].keys() == template[section].keys(), section
        for key, values in single[section].items():
            if values != template[section][key]:
                assert all("%i" in value for value in template[section][key]), key


def _runnable_units(folder: Path) -> list[Path]:
    """Copies of the units whose ExecStart names an executable that exists here."""
    beside = Path(sys.executable).with_name("hostd")
    executable = beside if beside.exists() else Path(shutil.which("hostd") or sys.executable)
    copies = []
    for name in UNITS:
        text = (SYSTEMD / name).read_text().replace("/usr/local/bin/hostd", str(executable))
        copy = folder / name.replace("@.", "@left.")
        copy.write_text(text)
        copies.append(copy)
    return copies


def test_systemd_analyze_verify_accepts_the_units(tmp_path: Path) -> None:
    analyze = shutil.which("systemd-analyze")
    if analyze is None:
        pytest.skip("systemd-analyze is not installed (Debian package systemd)")
    for unit in _runnable_units(tmp_path):
        result = subprocess.run(
            [analyze, "verify", str(unit)], capture_output=True, text=True, timeout=60
        )
        complaints = [line for line in (result.stdout + result.stderr).splitlines()
                      if unit.name in line or "hostd" in line]
        assert result.returncode == 0, result.stdout + result.stderr
        assert not complaints, result.stdout + result.stderr


def test_sysusers_and_tmpfiles_make_the_user_and_folders(tmp_path: Path) -> None:
    sysusers, tmpfiles = shutil.which("systemd-sysusers"), shutil.which("systemd-tmpfiles")
    if sysusers is None or tmpfiles is None:
        pytest.skip("systemd-sysusers or systemd-tmpfiles is not installed")
    root = tmp_path / "root"
    (root / "etc").mkdir(parents=True)
    (root / "etc" / "passwd").write_text("root:x:0:0:root:/root:/bin/sh\n")
    (root / "etc" / "group").write_text("root:x:0:\ndialout:x:20:\n")
    subprocess.run([sysusers, f"--root={root}", str(SYSTEMD / "hostd.sysusers.conf")],
                   check=True, capture_output=True, timeout=60)
    users = {line.split(":")[0]: line.split(":") for line in
             (root / "etc" / "passwd").read_text().splitlines()}
    groups = {line.split(":")[0]: line.split(":") for line in
              (root / "etc" / "group").read_text().splitlines()}
    assert users["hostd"][5] == "/var/lib/hostd"
    assert "hostd" in groups["dialout"][3].split(",")
    uid = int(users["hostd"][2])
    assert 0 < uid < 1000, "a system user"

    subprocess.run([tmpfiles, f"--root={root}", "--create", str(SYSTEMD / "hostd.tmpfiles.conf")],
                   check=True, capture_output=True, timeout=60)
    state, jobs = root / "var/lib/hostd", root / "var/lib/hostd/jobs"
    if os.geteuid() == 0:  # only root can hand the folders to hostd
        assert state.stat().st_uid == uid
        assert jobs.stat().st_uid == uid
    assert stat.S_IMODE(state.stat().st_mode) == 0o750
    assert stat.S_IMODE(jobs.stat().st_mode) == 0o2770


def _install(destdir: Path, *ids: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "DESTDIR": str(destdir), "HOSTD_SKIP_VENV": "1"}
    return subprocess.run(["sh", str(SYSTEMD / "install.sh"), *ids], env=env,
                          capture_output=True, text=True, timeout=60)


def _under_read_write_paths(folder: Path, unit: str, instance: str) -> bool:
    service = parse_unit(SYSTEMD / unit)["Service"]
    writable = [PurePosixPath(path.lstrip("-").replace("%i", instance))
                for path in service["ReadWritePaths"]]
    return any(PurePosixPath(folder).is_relative_to(path) for path in writable)


def test_install_script_stages_units_and_working_configs(tmp_path: Path) -> None:
    result = _install(tmp_path)
    assert result.returncode == 0, result.stderr
    for path in ["etc/systemd/system/hostd.service", "etc/systemd/system/hostd@.service",
                 "usr/lib/sysusers.d/hostd.conf", "usr/lib/tmpfiles.d/hostd.conf"]:
        assert (tmp_path / path).is_file(), path
    assert os.readlink(tmp_path / "usr/local/bin/hostd") == "/opt/hostd/bin/hostd"
    config_file = tmp_path / "etc/hostd/hostd.toml"
    assert stat.S_IMODE(config_file.stat().st_mode) == 0o640  # it may hold the MQTT password
    config = load_config(config_file)
    assert config.state.folder == Path("/var/lib/hostd")
    for folder in (config.state.folder, config.jobs.folder):
        assert _under_read_write_paths(folder, "hostd.service", "")
    assert "systemctl enable --now hostd.service" in result.stdout

    config_file.write_text(config_file.read_text().replace("printer1", "edited"))
    assert _install(tmp_path).returncode == 0
    assert load_config(config_file).printer.id == "edited", "configs are never overwritten"


def test_install_script_makes_one_config_per_template_instance(tmp_path: Path) -> None:
    result = _install(tmp_path, "left", "right")
    assert result.returncode == 0, result.stderr
    for printer in ("left", "right"):
        config = load_config(tmp_path / f"etc/hostd/{printer}.toml")
        assert config.printer.id == printer
        assert config.state.folder == Path(f"/var/lib/hostd/{printer}")
        assert config.jobs.folder == Path(f"/var/lib/hostd/{printer}/jobs")
        for folder in (config.state.folder, config.jobs.folder):
            assert _under_read_write_paths(folder, "hostd@.service", printer)
    assert "hostd@left.service hostd@right.service" in result.stdout
    refused = _install(tmp_path, "../evil")
    assert refused.returncode == 2
    assert "printer id" in refused.stderr
