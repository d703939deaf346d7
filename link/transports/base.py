"""The Transport interface every medium implements (the scheme table is link.transports.table).

Takes in: an address and channel names (from a connection string, through the table).
Gives out: a Transport to open. Frames are opaque bytes here; MAVLink framing lives in link.mavlink.codec.

Contract every transport meets (tests/link/test_transport_contract.py runs it on each scheme):
- `open()` / `close()` are idempotent; the transport is a context manager.
- `send(frame)` hands one frame to the medium and never blocks for long; it returns False if the
  medium refused it (counted in stats.send_errors).
- `receive(timeout_s)` returns every chunk that has arrived, waiting at most `timeout_s` for the first;
  datagram transports return whole frames, stream transports (serial) arbitrary byte chunks, which the
  codec's stream parser reassembles. It never raises for a closed or empty medium: it returns [].
- Channels: keyed transports (zenoh, mem) publish on `tx` and subscribe to `rx`; point-to-point
  transports (udp, serial) ignore channel names: the address is the channel.
"""

from __future__ import annotations

import abc
import socket
from dataclasses import dataclass


@dataclass
class TransportStats:
    frames_sent: int = 0
    bytes_sent: int = 0
    chunks_received: int = 0
    bytes_received: int = 0
    send_errors: int = 0

    def record_send(self, frame_len: int, ok: bool) -> bool:
        """Count one send: a frame handed to the medium, or one the medium refused. Returns ok."""
        if ok:
            self.frames_sent += 1
            self.bytes_sent += frame_len
        else:
            self.send_errors += 1
        return ok

    def snapshot(self) -> TransportStats:
        return TransportStats(**vars(self))


class Transport(abc.ABC):
    """A bidirectional pipe of frames. Subclasses set `scheme` and implement the four methods."""

    scheme: str = ""

    def __init__(self, address: str, tx: str | None = None, rx: str | None = None, **options):
        self.address = address
        self.tx = tx
        self.rx = rx
        self.options = options
        self.stats = TransportStats()
        self.is_open = False

    @abc.abstractmethod
    def open(self) -> None: ...

    @abc.abstractmethod
    def close(self) -> None: ...

    @abc.abstractmethod
    def send(self, frame: bytes) -> bool: ...

    @abc.abstractmethod
    def receive(self, timeout_s: float = 0.0) -> list[bytes]: ...

    def __enter__(self) -> Transport:
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def describe(self) -> str:
        return f"{self.scheme}:{self.address}"


def free_loopback_port(kind: int = socket.SOCK_STREAM) -> int:
    """A port on 127.0.0.1 (TCP, or UDP with socket.SOCK_DGRAM) that nothing is bound to right now: bind to
    port 0, read the kernel's choice back, release it. For private loopback endpoints (an emulator child,
    tests, benchmarks); another process may take it before it is used, which is rare on a test machine."""
    with socket.socket(socket.AF_INET, kind) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]
