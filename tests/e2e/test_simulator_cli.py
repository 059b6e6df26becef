"""`hostd simulate` prints a device path that pyserial opens and talks Marlin on."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest
import serial
from support.waiting import wait_until

from drivers.link.protocol import frame


@pytest.mark.parametrize("stop_signal", [signal.SIGTERM, signal.SIGINT])
def test_hostd_simulate_serves_a_port_until_signalled(tmp_path, stop_signal):
    log = tmp_path / "executed.log"
    proc = subprocess.Popen(
        [sys.executable, "-m", "hostd.app.cli", "simulate", "--time-scale", "0", "--baud", "0",
         "--log", str(log), "--advanced-ok"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        path = proc.stdout.readline().strip()
        assert path.startswith("/dev/"), path
        with serial.Serial(path, 250000, timeout=3) as port:
            assert port.readline() == b"start\n"
            port.readline()
            port.readline()
            port.write(frame(1, "M105"))
            reply = port.readline().decode()
            assert reply.startswith("ok T:"), reply
            port.write(frame(2, "G1 X10 F600"))
            assert port.readline() == b"ok N2 P15 B3\n"
        wait_until(lambda: log.read_text().splitlines() == ["M105", "G1 X10 F600"], 3,
                   log.read_text)
        proc.send_signal(stop_signal)
        assert proc.wait(timeout=5) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
        proc.stderr.close()


def test_hostd_simulate_faults_and_link(tmp_path):
    link = tmp_path / "printer"
    proc = subprocess.Popen(
        [sys.executable, "-m", "hostd.app.cli", "simulate", "--time-scale", "0", "--baud", "0",
         "--fault", "drop_ok=1", "--seed", "3", "--link", str(link)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        path = proc.stdout.readline().strip()
        assert link.resolve() == Path(path)
        with serial.Serial(str(link), 250000, timeout=0.5) as port:
            assert port.readline() == b"start\n"
            port.readline()
            port.readline()
            port.write(frame(1, "G1 X1"))
            assert port.readline() == b""  # every ok dropped
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=5) == 0
        assert not link.exists()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
        proc.stderr.close()


def test_hostd_simulate_rejects_an_unknown_fault():
    hostd = Path(sys.executable).parent / "hostd"  # the console script, as users run it
    result = subprocess.run(
        [str(hostd), "simulate", "--fault", "gremlins=0.1"],
        capture_output=True, text=True, timeout=20,
    )
    assert result.returncode == 2
    assert "gremlins" in result.stderr
    assert result.stdout == ""
