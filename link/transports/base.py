"""The Transport interface and the scheme -> class table.

Takes in: a connection string and channel names.
Gives out: an opened Transport. Frames are opaque bytes here; MAVLink framing lives in link.codec.

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
from dataclasses import dataclass

from link.errors import UserError


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


SCHEMES: dict[str, type[Transport]] = {}


def register_scheme(cls: type[Transport]) -> type[Transport]:
    """Class decorator adding a transport to the table under `cls.scheme`."""
    if not cls.scheme:
        raise ValueError(f"{cls.__name__} has no scheme")
    SCHEMES[cls.scheme] = cls
    return cls


def parse_connection(connection: str) -> tuple[str, str]:
    """Split 'scheme:address'. A bare 'zenoh' means zenoh with its defaults."""
    scheme, sep, address = connection.partition(":")
    if not sep and scheme != "zenoh":
        raise UserError(f"connection string '{connection}' has no scheme (expected SCHEME:ADDRESS, "
                        f"schemes: {', '.join(sorted(_table()))})")
    return scheme, address


def _table() -> dict[str, type[Transport]]:
    # Importing the modules fills SCHEMES; the explicit list below is the scheme table.
    from link.transports import mem, serial_stream, udp, zenoh_transport  # noqa: F401

    return SCHEMES


def open_transport(connection: str, tx: str | None = None, rx: str | None = None, **options) -> Transport:
    """Build and open the transport a connection string names."""
    scheme, address = parse_connection(connection)
    table = _table()
    if scheme not in table:
        raise UserError(f"unknown transport scheme '{scheme}' in '{connection}' "
                        f"(one of: {', '.join(sorted(table))})")
    transport = table[scheme](address, tx=tx, rx=rx, **options)
    transport.open()
    return transport
