"""`mem:NAME` - an in-process bus, for tests and for running several components in one process.

Takes in: a bus NAME (any non-empty text); every transport opened on the same NAME shares one bus.
Options: `queue_frames` (receive queue bound per transport, default DEFAULT_QUEUE_FRAMES).
Gives out: a keyed transport. It publishes on channel `tx` and receives what OTHER transports on the
bus publish on channel `rx` (never its own frames). A channel left as None is the bus's common
channel "", so two transports opened without channel names simply talk to each other.

Thread-safe: the bus is guarded by a lock and each receiver owns a bounded queue.Queue. A full
receive queue drops the newest frame and counts it in the receiver's `frames_dropped`, the way a
slow reader loses datagrams, instead of ever blocking the sender.
"""

from __future__ import annotations

import queue
import threading

from link.transports.base import Transport
from model.errors import UserError

# Bound of each receive queue: a few seconds of a 1 kHz lockstep stream, small enough that a stalled
# reader is noticed (through frames_dropped) rather than growing memory without limit.
DEFAULT_QUEUE_FRAMES = 8192
COMMON_CHANNEL = ""


class _Bus:
    """The subscribers of one bus NAME, by channel."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.subscribers: dict[str, list[MemTransport]] = {}

    def publish(self, channel: str, frame: bytes, sender: MemTransport) -> None:
        with self.lock:
            receivers = list(self.subscribers.get(channel, ()))
        for receiver in receivers:
            if receiver is not sender:
                receiver._deliver(frame)

    def subscribe(self, channel: str, receiver: MemTransport) -> None:
        with self.lock:
            self.subscribers.setdefault(channel, []).append(receiver)

    def unsubscribe(self, channel: str, receiver: MemTransport) -> None:
        with self.lock:
            members = self.subscribers.get(channel, [])
            if receiver in members:
                members.remove(receiver)
            if not members:
                self.subscribers.pop(channel, None)

    def is_empty(self) -> bool:
        return not self.subscribers


_BUSES: dict[str, _Bus] = {}
_BUSES_LOCK = threading.Lock()


def _bus_named(name: str) -> _Bus:
    with _BUSES_LOCK:
        return _BUSES.setdefault(name, _Bus())


def _forget_bus_if_unused(name: str) -> None:
    with _BUSES_LOCK:
        bus = _BUSES.get(name)
        if bus is not None and bus.is_empty():
            del _BUSES[name]


class MemTransport(Transport):
    scheme = "mem"

    def __init__(self, address: str, tx: str | None = None, rx: str | None = None, **options):
        super().__init__(address, tx=tx, rx=rx, **options)
        if not address:
            raise UserError("mem transport needs a bus name (expected mem:NAME)")
        unknown = set(options) - {"queue_frames"}
        if unknown:
            raise UserError(f"mem:{address}: unknown option(s) {', '.join(sorted(unknown))} "
                            "(known: queue_frames)")
        capacity = int(options.get("queue_frames", DEFAULT_QUEUE_FRAMES))
        if capacity < 1:
            raise UserError(f"mem:{address}: queue_frames must be >= 1, got {capacity}")
        self.tx_channel = COMMON_CHANNEL if tx is None else tx
        self.rx_channel = COMMON_CHANNEL if rx is None else rx
        self.frames_dropped = 0
        self._drop_lock = threading.Lock()  # senders on several threads may drop at once
        self._inbox: queue.Queue[bytes] = queue.Queue(maxsize=capacity)
        self._bus: _Bus | None = None

    def open(self) -> None:
        if self.is_open:
            return
        self._bus = _bus_named(self.address)
        self._bus.subscribe(self.rx_channel, self)
        self.is_open = True

    def close(self) -> None:
        if not self.is_open:
            return
        self.is_open = False
        self._bus.unsubscribe(self.rx_channel, self)
        _forget_bus_if_unused(self.address)
        self._bus = None
        self._drain_inbox()

    def send(self, frame: bytes) -> bool:
        if not self.is_open:
            return self.stats.record_send(len(frame), False)
        frame = bytes(frame)
        self._bus.publish(self.tx_channel, frame, sender=self)
        return self.stats.record_send(len(frame), True)

    def receive(self, timeout_s: float = 0.0) -> list[bytes]:
        if not self.is_open:
            return []
        chunks = self._drain_inbox()
        if not chunks and timeout_s > 0:
            try:
                chunks.append(self._inbox.get(timeout=timeout_s))
            except queue.Empty:
                return []
            chunks.extend(self._drain_inbox())
        self.stats.chunks_received += len(chunks)
        self.stats.bytes_received += sum(len(chunk) for chunk in chunks)
        return chunks

    def _deliver(self, frame: bytes) -> None:
        """Called by the bus on the SENDER's thread; must never block it."""
        try:
            self._inbox.put_nowait(frame)
        except queue.Full:
            with self._drop_lock:
                self.frames_dropped += 1

    def _drain_inbox(self) -> list[bytes]:
        chunks = []
        while True:
            try:
                chunks.append(self._inbox.get_nowait())
            except queue.Empty:
                return chunks
