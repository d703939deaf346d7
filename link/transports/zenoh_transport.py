"""`zenoh:[ENDPOINT[,ENDPOINT]]` - frames as zenoh samples on key expressions (the default scheme).

Takes in: endpoints to connect to (e.g. `zenoh:tcp/127.0.0.1:7447`; bare `zenoh` connects nowhere
and only reaches this process and whoever connects to it), the keys `tx` (publish on) and `rx`
(subscribe to), and options:
  session: `mode` ("peer" default | "client" | "router"), `connect` / `listen` (lists of endpoints),
           `scouting` (multicast scouting, default off), `config_file` (zenoh JSON5 config);
  transport: `queue_frames` (receive buffer bound, default DEFAULT_QUEUE_FRAMES),
             `express` (never batch this publisher's samples, default DEFAULT_EXPRESS = False).
Gives out: a keyed transport; each send() is one sample, each received sample one frame.
A peer opens even if the endpoint it connects to is not up yet (zenoh keeps retrying); a client needs
its router up at open (else UserError). zenoh keeps no history: a sample published before the other
end's subscriber is known is lost, so a starting sender calls wait_for_subscribers().

Design:
- Every zenoh transport with the same session settings shares one session (link.zenoh_session).
  Transports in one process reach each other through it; a transport whose tx equals its rx hears
  its own frames.
- Publishing uses a declared Publisher, reliability RELIABLE and congestion control BLOCK, so a lockstep
  frame is never silently dropped: a slow reader slows the writer down instead. Not express by default:
  measured on loopback (2 processes, 60 B ping-pong), express changed neither p50 (~0.3 ms) nor p99,
  idle or under a 5 kHz side stream, because zenoh sends a lone sample at once anyway; but it cut a
  burst's throughput ~10x (15 k vs 160-250 k frames/s), since every sample became its own write.
- Receiving uses a bounded FIFO channel (zenoh.handlers.FifoChannel). One reader thread per transport
  moves samples from it into a queue.Queue that receive() waits on with a timeout; zenoh is never
  called from inside a zenoh callback. Closing undeclares the subscriber, which ends the reader (its
  blocking recv() releases the GIL). Polling try_recv() with sleeps instead measured a similar p50
  but a worse p99 (0.5-0.7 ms vs 0.4-0.6 ms).
"""

from __future__ import annotations

import atexit
import queue
import threading
import time
import weakref

import zenoh

from link.errors import UserError
from link.transports.base import Transport, register_scheme
from link.zenoh_session import (
    SESSION_OPTIONS,
    ZenohSettings,
    acquire_session,
    release_session,
    zenoh_error_text,
)

# Bound of the receive buffer (zenoh FIFO and our queue each): several seconds of a 1 kHz stream.
DEFAULT_QUEUE_FRAMES = 8192
TRANSPORT_OPTIONS = ("queue_frames", "express")
DEFAULT_EXPRESS = False  # see the module docstring for the measurement behind this
# How long close() waits for the reader thread, which ends as soon as the subscriber is undeclared.
READER_JOIN_TIMEOUT_S = 2.0
# How often the reader re-checks for close() while our queue is full (the consumer is behind).
FULL_QUEUE_RETRY_S = 0.05
MATCHING_POLL_S = 0.005

_OPEN_TRANSPORTS: weakref.WeakSet[ZenohTransport] = weakref.WeakSet()


@register_scheme
class ZenohTransport(Transport):
    scheme = "zenoh"

    def __init__(self, address: str, tx: str | None = None, rx: str | None = None, **options):
        super().__init__(address, tx=tx, rx=rx, **options)
        unknown = set(options) - set(SESSION_OPTIONS) - set(TRANSPORT_OPTIONS)
        if unknown:
            raise UserError(f"zenoh:{address}: unknown option(s) {', '.join(sorted(unknown))} "
                            f"(known: {', '.join(SESSION_OPTIONS + TRANSPORT_OPTIONS)})")
        if tx is None and rx is None:
            raise UserError(f"zenoh:{address}: a zenoh transport needs a key to send on (tx) "
                            "or to receive from (rx)")
        session_options = {name: value for name, value in options.items() if name in SESSION_OPTIONS}
        self.settings = ZenohSettings.from_options(address, **session_options)
        self.capacity = int(options.get("queue_frames", DEFAULT_QUEUE_FRAMES))
        if self.capacity < 1:
            raise UserError(f"zenoh:{address}: queue_frames must be >= 1, got {self.capacity}")
        self.express = bool(options.get("express", DEFAULT_EXPRESS))
        self._inbox: queue.Queue[bytes] = queue.Queue(maxsize=self.capacity)
        self._closing = threading.Event()
        self._session: zenoh.Session | None = None
        self._publisher: zenoh.Publisher | None = None
        self._subscriber: zenoh.Subscriber | None = None
        self._reader: threading.Thread | None = None

    def open(self) -> None:
        if self.is_open:
            return
        tx_key = _key(self.tx, "tx") if self.tx is not None else None
        rx_key = _key(self.rx, "rx") if self.rx is not None else None
        self._session = acquire_session(self.settings)
        self._closing.clear()
        try:
            if tx_key is not None:
                self._publisher = self._session.declare_publisher(
                    tx_key, reliability=zenoh.Reliability.RELIABLE,
                    congestion_control=zenoh.CongestionControl.BLOCK, express=self.express)
            if rx_key is not None:
                self._subscriber = self._session.declare_subscriber(
                    rx_key, zenoh.handlers.FifoChannel(self.capacity))
                self._reader = threading.Thread(target=self._read_samples, args=(self._subscriber.handler,),
                                                name=f"zenoh-rx {self.rx}", daemon=True)
                self._reader.start()
        except zenoh.ZError as err:
            self._undeclare()
            release_session(self.settings)
            self._session = None
            reason = zenoh_error_text(err)
            raise UserError(f"zenoh: cannot declare tx={self.tx!r} rx={self.rx!r}: {reason}") from None
        self.is_open = True
        _OPEN_TRANSPORTS.add(self)

    def close(self) -> None:
        if not self.is_open:
            return
        self.is_open = False
        _OPEN_TRANSPORTS.discard(self)
        self._closing.set()
        self._undeclare()
        if self._reader is not None:
            self._reader.join(READER_JOIN_TIMEOUT_S)
            self._reader = None
        release_session(self.settings)
        self._session = None
        _drain(self._inbox)

    def send(self, frame: bytes) -> bool:
        if not self.is_open or self._publisher is None:
            self.stats.send_errors += 1
            return False
        try:
            self._publisher.put(bytes(frame))
        except zenoh.ZError:  # the session was closed under us
            self.stats.send_errors += 1
            return False
        self.stats.frames_sent += 1
        self.stats.bytes_sent += len(frame)
        return True

    def receive(self, timeout_s: float = 0.0) -> list[bytes]:
        if not self.is_open:
            return []
        frames = _drain(self._inbox)
        if not frames and timeout_s > 0:
            try:
                frames.append(self._inbox.get(timeout=timeout_s))
            except queue.Empty:
                return []
            frames.extend(_drain(self._inbox))
        self.stats.chunks_received += len(frames)
        self.stats.bytes_received += sum(len(frame) for frame in frames)
        return frames

    def has_subscribers(self) -> bool:
        """True when some subscriber (here or remote) matches our tx key."""
        if not self.is_open or self._publisher is None:
            return False
        return bool(self._publisher.matching_status.matching)

    def wait_for_subscribers(self, timeout_s: float) -> bool:
        """Wait until a subscriber matches our tx key (zenoh keeps no history: earlier samples are lost)."""
        deadline = time.monotonic() + timeout_s
        while not self.has_subscribers():
            if time.monotonic() >= deadline:
                return False
            time.sleep(MATCHING_POLL_S)
        return True

    def describe(self) -> str:
        return f"zenoh:{self.address} ({self.settings.describe()}) tx={self.tx} rx={self.rx}"

    def _read_samples(self, handler) -> None:
        """Reader thread: FIFO channel -> our queue, until the subscriber is undeclared."""
        while True:
            try:
                sample = handler.recv()
            except zenoh.ZError:  # channel closed: subscriber undeclared or session closed
                return
            frame = sample.payload.to_bytes()
            while not self._closing.is_set():
                try:
                    self._inbox.put(frame, timeout=FULL_QUEUE_RETRY_S)
                    break
                except queue.Full:
                    continue  # the consumer is behind: hold the FIFO, which slows the sender

    def _undeclare(self) -> None:
        for entity in (self._subscriber, self._publisher):
            if entity is not None:
                try:
                    entity.undeclare()
                except zenoh.ZError:
                    pass  # already gone with its session
        self._subscriber = None
        self._publisher = None


def _key(key: str, role: str) -> zenoh.KeyExpr:
    try:
        return zenoh.KeyExpr(key)
    except zenoh.ZError as err:
        reason = zenoh_error_text(err)
        raise UserError(f"zenoh {role} key '{key}' is not a valid key expression ({reason})") from None


def _drain(inbox: queue.Queue) -> list[bytes]:
    frames = []
    while True:
        try:
            frames.append(inbox.get_nowait())
        except queue.Empty:
            return frames


def _close_open_transports() -> None:
    # Reader threads blocked inside zenoh must end before the interpreter does, or it aborts.
    for transport in list(_OPEN_TRANSPORTS):
        transport.close()


atexit.register(_close_open_transports)
