"""The serial transport on a real pseudo-terminal: lines both ways, never blocking, unplugging."""

from __future__ import annotations

import asyncio
import os
import tty

import pytest
from support.waiting import until

from drivers.link.errors import LinkError, PrinterLinkError, StreamCancelled
from drivers.link.transport import TransportError, open_transport


def _pty() -> tuple[int, str]:
    master, slave = os.openpty()
    tty.setraw(slave)
    path = os.ttyname(slave)
    os.close(slave)
    return master, path


def _read_master(master: int, size: int) -> bytes:
    out = b""
    while len(out) < size:
        out += os.read(master, size - len(out))
    return out


def test_lines_both_ways_and_partial_lines():
    async def run() -> list[str]:
        master, path = _pty()
        try:
            transport = await open_transport(path, 115200)
            async with transport:
                await transport.write(b"N1 G28*18\n")
                got = await asyncio.get_running_loop().run_in_executor(
                    None, _read_master, master, 10)
                assert got == b"N1 G28*18\n"
                os.write(master, b"ok\r\nResend: 3\nT:20")
                first = await asyncio.wait_for(transport.readline(), 2)
                second = await asyncio.wait_for(transport.readline(), 2)
                os.write(master, b".0 /0.0\n")
                third = await asyncio.wait_for(transport.readline(), 2)
                return [first, second, third]
        finally:
            os.close(master)

    assert asyncio.run(run()) == ["ok", "Resend: 3", "T:20.0 /0.0"]


def test_serve_hands_each_line_to_the_reader_as_it_arrives_until_the_port_ends():
    # the link's reader acts on each line in the read callback (no task switch per line):
    # lines received before serve() first, then each as it arrives, in order, and the
    # other end closing ends serve() with a TransportError
    async def run() -> list[str]:
        master, path = _pty()
        got: list[str] = []
        transport = await open_transport(path, 115200)
        async with transport:
            os.write(master, b"start\n")
            await until(lambda: transport.bytes_read == 6)
            serving = asyncio.create_task(transport.serve(got.append), name="serve")
            os.write(master, b"ok\r\nResend: 3\nT:20")
            await until(lambda: got == ["start", "ok", "Resend: 3"])
            os.write(master, b".0 /0.0\n")
            await until(lambda: len(got) == 4)
            os.close(master)
            with pytest.raises(TransportError):
                await asyncio.wait_for(serving, 2)
        return got

    assert asyncio.run(run()) == ["start", "ok", "Resend: 3", "T:20.0 /0.0"]


def test_waiting_for_a_line_does_not_block_the_loop():
    async def run() -> int:
        master, path = _pty()
        ticks = 0

        async def ticker() -> None:
            nonlocal ticks
            while True:
                await asyncio.sleep(0.01)
                ticks += 1

        try:
            async with await open_transport(path, 250000) as transport:
                task = asyncio.create_task(ticker(), name="ticker")
                with pytest.raises(TimeoutError):
                    await asyncio.wait_for(transport.readline(), 0.3)
                task.cancel()
                return ticks
        finally:
            os.close(master)

    assert asyncio.run(run()) >= 10


def test_unplugging_fails_a_pending_read_within_a_second():
    async def run() -> float:
        master, path = _pty()
        async with await open_transport(path, 250000) as transport:
            loop = asyncio.get_running_loop()
            reader = asyncio.create_task(transport.readline(), name="reader")
            await until(lambda: transport._readers, 2, "the read to be waiting")
            unplugged = loop.time()
            os.close(master)
            with pytest.raises(TransportError):
                await asyncio.wait_for(reader, 1.0)
            with pytest.raises(TransportError):
                await transport.write(b"M105\n")
            assert not transport.is_open
            return loop.time() - unplugged

    assert asyncio.run(run()) < 1.0


def test_opening_a_missing_port_is_a_transport_error(tmp_path):
    async def run() -> None:
        await open_transport(str(tmp_path / "no-such-port"), 115200)

    with pytest.raises(TransportError, match="cannot open"):
        asyncio.run(run())


def test_close_fails_pending_reads():
    async def run() -> None:
        master, path = _pty()
        try:
            transport = await open_transport(path, 250000)
            reader = asyncio.create_task(transport.readline(), name="reader")
            await until(lambda: transport._readers, 2, "the read to be waiting")
            await transport.close()
            with pytest.raises(TransportError):
                await asyncio.wait_for(reader, 1.0)
        finally:
            os.close(master)

    asyncio.run(run())


def test_link_errors_share_one_base() -> None:
    """A caller catches any error of the printer link as one, and the port's failures
    still as the ``ConnectionError`` (an ``OSError``) they are."""
    for kind in (LinkError, TransportError, StreamCancelled):
        assert issubclass(kind, PrinterLinkError)
    assert issubclass(LinkError, OSError)
    assert issubclass(TransportError, OSError)
    assert not issubclass(StreamCancelled, OSError)
