"""Fixtures for the transport tests: free ports, ptys, a pty "null-modem cable", background receivers,
a zenoh router in a child process.

Gives out (fixtures): `free_tcp_port` / `free_udp_port` (a function returning a port), `pty_pair`
((master fd, slave device)), `null_modem` ((device A, device B) wired TX->RX both ways), `transfer`
(a function: send frames while a thread receives them on the other end, as a real peer would),
`zenoh_router` (a RouterProcess).
"""

from __future__ import annotations

import contextlib
import functools
import os
import select
import socket
import subprocess
import sys
import threading
import time
import tty
from collections.abc import Iterator
from dataclasses import dataclass

import pytest
from testsupport import free_port

from link.transports.base import Transport


@contextlib.contextmanager
def _pty_pair() -> Iterator[tuple[int, str]]:
    """(master fd, slave device path) of a raw pseudo-terminal; the slave stays open meanwhile, so
    the master never sees a hang-up while a transport reopens the slave by name."""
    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        yield master, os.ttyname(slave)
    finally:
        os.close(slave)
        os.close(master)


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


@contextlib.contextmanager
def _null_modem() -> Iterator[tuple[str, str]]:
    """Two pty slave devices whose bytes cross over (like two UARTs wired TX->RX), via a bridge thread
    copying between the two masters."""
    with _pty_pair() as (master_a, device_a), _pty_pair() as (master_b, device_b):
        wake_r, wake_w = os.pipe()
        peer = {master_a: master_b, master_b: master_a}

        def bridge() -> None:
            while True:
                readable, _, _ = select.select([master_a, master_b, wake_r], [], [])
                if wake_r in readable:
                    return
                for fd in readable:
                    try:
                        _write_all(peer[fd], os.read(fd, 65536))
                    except OSError:
                        return

        thread = threading.Thread(target=bridge, name="pty null modem", daemon=True)
        thread.start()
        try:
            yield device_a, device_b
        finally:
            os.write(wake_w, b"x")
            thread.join(2.0)
            os.close(wake_r)
            os.close(wake_w)


class Collector:
    """Receives on a background thread until `expected_bytes` have arrived or `timeout_s` passes."""

    def __init__(self, transport: Transport, expected_bytes: int, timeout_s: float = 10.0):
        self.transport = transport
        self.expected_bytes = expected_bytes
        self.timeout_s = timeout_s
        self.chunks: list[bytes] = []
        self._thread = threading.Thread(target=self._run, name="collector", daemon=True)

    def __enter__(self) -> Collector:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._thread.join(self.timeout_s + 1.0)

    def _run(self) -> None:
        deadline = time.monotonic() + self.timeout_s
        received = 0
        while received < self.expected_bytes and time.monotonic() < deadline:
            chunks = self.transport.receive(0.05)
            self.chunks.extend(chunks)
            received += sum(len(chunk) for chunk in chunks)

    @property
    def data(self) -> bytes:
        return b"".join(self.chunks)


def _transfer(sender: Transport, receiver: Transport, frames: list[bytes],
              timeout_s: float = 10.0) -> list[bytes]:
    """Send `frames` while a collector receives them on the other end; what arrived, as chunks."""
    with Collector(receiver, sum(len(frame) for frame in frames), timeout_s) as collector:
        for frame in frames:
            assert sender.send(frame), f"{sender.describe()} refused a frame of {len(frame)} bytes"
    return collector.chunks


@contextlib.contextmanager
def _run_router(port: int) -> Iterator[subprocess.Popen]:
    """A zenoh router listening on tcp/127.0.0.1:PORT in a child process (link.transports.zenoh_session's main)."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "link.transports.zenoh_session", "--mode", "router",
         "--listen", f"tcp/127.0.0.1:{port}"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        ready, _, _ = select.select([proc.stdout], [], [], 15.0)
        line = proc.stdout.readline() if ready else ""
        if "ready" not in line:
            proc.kill()
            raise RuntimeError(f"zenoh router did not start: {line!r} {proc.stderr.read()!r}")
        yield proc
    finally:
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(5.0)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


@dataclass
class RouterProcess:
    endpoint: str  # e.g. tcp/127.0.0.1:40123
    process: subprocess.Popen


@pytest.fixture(scope="session")
def free_tcp_port():
    """A function returning a free loopback TCP port."""
    return free_port


@pytest.fixture(scope="session")
def free_udp_port():
    """A function returning a free loopback UDP port."""
    return functools.partial(free_port, socket.SOCK_DGRAM)


@pytest.fixture
def pty_pair() -> Iterator[tuple[int, str]]:
    with _pty_pair() as pair:
        yield pair


@pytest.fixture
def null_modem() -> Iterator[tuple[str, str]]:
    with _null_modem() as devices:
        yield devices


@pytest.fixture(scope="session")
def transfer():
    return _transfer


@pytest.fixture
def zenoh_router() -> Iterator[RouterProcess]:
    port = free_port()
    with _run_router(port) as process:
        yield RouterProcess(f"tcp/127.0.0.1:{port}", process)
