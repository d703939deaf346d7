"""`udpin:HOST:PORT` and `udpout:HOST:PORT` - plain UDP datagrams, one frame per datagram.

Takes in: an address HOST:PORT (IPv6 hosts in brackets: `[::1]:14550`). Options:
`socket_buffer_bytes` (kernel receive/send buffer request, default DEFAULT_SOCKET_BUFFER_BYTES).
Gives out: a point-to-point transport (channel names are ignored: the address is the channel), with
the semantics of MAVProxy / QGroundControl, so standard MAVLink tools can talk to us:
- udpin binds HOST:PORT and listens; it sends to the last peer that sent to it (nothing before that:
  send returns False and counts a send error).
- udpout sends to HOST:PORT from an ephemeral local port and receives the replies there.
Non-blocking sockets; receive waits with select() for at most `timeout_s`.
"""

from __future__ import annotations

import select
import socket

from link.transports.base import Transport
from model.errors import UserError

# Largest UDP payload; MAVLink 2 frames are at most 280 bytes but a peer may batch several.
MAX_DATAGRAM_BYTES = 65535
# Requested kernel buffer. A 2000-frame loopback burst of 280-byte frames needs ~2.5 MB of kernel
# memory (each datagram costs ~1.2 kB of skb overhead), more than Linux's default 208 kB.
DEFAULT_SOCKET_BUFFER_BYTES = 4 * 1024 * 1024
# Datagrams taken per receive() call, so a flooding peer cannot keep one call looping forever.
MAX_DATAGRAMS_PER_RECEIVE = 8192


def parse_host_port(scheme: str, address: str, allow_port_zero: bool) -> tuple[str, int]:
    """'HOST:PORT' or '[V6HOST]:PORT' -> (host, port); one-line UserError naming the address."""
    example = f"{scheme}:127.0.0.1:14550"
    host, sep, port_text = address.rpartition(":")
    if not sep or not host or not port_text:
        raise UserError(f"'{scheme}:{address}' is not {scheme}:HOST:PORT (e.g. {example})")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    try:
        port = int(port_text)
    except ValueError:
        raise UserError(f"'{scheme}:{address}': port '{port_text}' is not a number "
                        f"(e.g. {example})") from None
    lowest = 0 if allow_port_zero else 1
    if not lowest <= port <= 65535:
        raise UserError(f"'{scheme}:{address}': port {port} is outside {lowest}..65535")
    return host, port


def resolve_udp(scheme: str, host: str, port: int) -> tuple[int, tuple]:
    """(address family, socket address) of HOST:PORT, or a UserError if the host is unknown."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)
    except socket.gaierror as err:
        raise UserError(f"{scheme}: cannot resolve host '{host}' ({err.strerror})") from None
    # IPv4 first when a name has both (e.g. localhost), as MAVLink tools speak IPv4.
    family, _, _, _, sockaddr = min(infos, key=lambda info: info[0] != socket.AF_INET)
    return family, sockaddr


class _UdpTransport(Transport):
    """What udpin and udpout share: a non-blocking datagram socket and select()-based receive."""

    allow_port_zero = False

    def __init__(self, address: str, tx: str | None = None, rx: str | None = None, **options):
        super().__init__(address, tx=tx, rx=rx, **options)
        unknown = set(options) - {"socket_buffer_bytes"}
        if unknown:
            raise UserError(f"{self.describe()}: unknown option(s) {', '.join(sorted(unknown))} "
                            "(known: socket_buffer_bytes)")
        self.buffer_bytes = int(options.get("socket_buffer_bytes", DEFAULT_SOCKET_BUFFER_BYTES))
        self.host, self.port = parse_host_port(self.scheme, address, self.allow_port_zero)
        self.peer: tuple | None = None
        self._sock: socket.socket | None = None

    @property
    def local_address(self) -> tuple | None:
        """The bound (host, port), e.g. to learn the port a `udpin:127.0.0.1:0` was given."""
        return self._sock.getsockname() if self._sock is not None else None

    def _new_socket(self, family: int) -> socket.socket:
        sock = socket.socket(family, socket.SOCK_DGRAM)
        for option in (socket.SO_RCVBUF, socket.SO_SNDBUF):
            # The kernel caps the request at net.core.[rw]mem_max; a smaller buffer still works.
            sock.setsockopt(socket.SOL_SOCKET, option, self.buffer_bytes)
        sock.setblocking(False)
        return sock

    def close(self) -> None:
        if not self.is_open:
            return
        self.is_open = False
        self._sock.close()
        self._sock = None

    def send(self, frame: bytes) -> bool:
        if not self.is_open or self.peer is None:
            return self.stats.record_send(len(frame), False)
        try:
            self._sock.sendto(frame, self.peer)
        except OSError:  # EAGAIN with a full send buffer, ENETUNREACH, ...: the medium refused it
            return self.stats.record_send(len(frame), False)
        return self.stats.record_send(len(frame), True)

    def receive(self, timeout_s: float = 0.0) -> list[bytes]:
        if not self.is_open:
            return []
        try:
            readable, _, _ = select.select([self._sock], [], [], max(0.0, timeout_s))
        except (OSError, ValueError):  # closed from another thread meanwhile
            return []
        if not readable:
            return []
        frames = self._drain()
        self.stats.chunks_received += len(frames)
        self.stats.bytes_received += sum(len(frame) for frame in frames)
        return frames

    def _drain(self) -> list[bytes]:
        frames = []
        while len(frames) < MAX_DATAGRAMS_PER_RECEIVE:
            try:
                frame, sender = self._sock.recvfrom(MAX_DATAGRAM_BYTES)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:  # e.g. an ICMP error reported on the socket: not a frame
                break
            self._note_sender(sender)
            frames.append(frame)
        return frames

    def _note_sender(self, sender: tuple) -> None:
        """udpin replies to whoever spoke last; udpout keeps its fixed destination."""


class UdpInTransport(_UdpTransport):
    scheme = "udpin"
    allow_port_zero = True  # port 0: the kernel picks a free port (see local_address)

    def open(self) -> None:
        if self.is_open:
            return
        family, sockaddr = resolve_udp(self.scheme, self.host, self.port)
        sock = self._new_socket(family)
        try:
            sock.bind(sockaddr)
        except OSError as err:
            sock.close()
            raise UserError(f"{self.describe()}: cannot bind ({err.strerror})") from None
        self._sock = sock
        self.is_open = True

    def _note_sender(self, sender: tuple) -> None:
        self.peer = sender


class UdpOutTransport(_UdpTransport):
    scheme = "udpout"

    def open(self) -> None:
        if self.is_open:
            return
        family, sockaddr = resolve_udp(self.scheme, self.host, self.port)
        sock = self._new_socket(family)
        # Bind the ephemeral port now, so replies can arrive (and be waited for) before the first send.
        sock.bind(("::", 0) if family == socket.AF_INET6 else ("0.0.0.0", 0))
        self._sock = sock
        self.peer = sockaddr
        self.is_open = True
