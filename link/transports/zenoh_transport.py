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
- Every zenoh transport with the same session settings shares one session (link.transports.zenoh_session).
  Transports in one process reach each other through it; a transport whose tx equals its rx hears
  its own frames.
- Publishing uses a declared Publisher, reliability RELIABLE and congestion control BLOCK, so a lockstep
  frame is never silently dropped: a slow reader slows the writer down instead. Not express by default:
  measured on loopback (2 processes, 60 B ping-pong), express changed neither p50 (~0.3 ms) nor p99,
  idle or under a 5 kHz side stream, because zenoh sends a lone sample at once anyway; but it cut a
  burst's throughput ~10x (15 k vs 160-250 k frames/s), since every sample became its own write.
- Receiving reads zenoh's bounded FIFO channel (zenoh.handlers.FifoChannel) in the caller's own
  thread: no Python thread sits between zenoh and receive(), so a frame costs no thread handoff and
  no GIL hand-over, and zenoh's network threads never wait for the GIL (nothing of ours runs in a
  zenoh callback; zenoh is never called from inside one). receive(0) drains the FIFO with
  try_recv(). receive(timeout > 0) with nothing there blocks in the FIFO's recv(), which has no
  timeout in zenoh's API: a per-transport waker thread, started on the first such wait, ends the wait
  at its deadline by publishing a session-local DELETE sample on the rx key whose attachment names
  this transport and this wait (Locality.SESSION_LOCAL: it never leaves the process). Only PUT
  samples are frames: wakes, stale wakes, wakes of another transport whose rx key overlaps ours in
  the same session, and remote DELETEs are skipped. A DELETE never has a payload, so a sample with a
  payload is taken as a frame without reading its kind (one zenoh call less per frame; the kind is
  read for empty samples only, an empty PUT being an empty frame). The waker sleeps until the newest
  deadline and is only woken when a wait ends earlier than it planned, so a wait answered in time
  costs it nothing.
  One thread waits in recv() at a time; a second concurrent receive() waits for its turn, then
  drains. Closing undeclares the subscriber, which ends a blocked recv(). A full FIFO blocks zenoh's
  delivery, which (RELIABLE, BLOCK) slows the sender down.
  Measured with `cfstack link-bench` (loopback, 2 processes, 2000 round trips of a 36 B frame out and
  a 73 B frame back, 3 alternating runs on a shared 2-core VM) against the previous design (one reader
  thread per transport moving samples from the FIFO into a queue.Queue), p50 over bare zenoh (a raw
  publisher + FIFO subscriber with a blocking recv, same session, same run):
      transport alone: previous +89..+120 us (1.50-1.59x), this design +31..+48 us (1.15-1.40x);
      full link (Endpoint, codec both ends): previous 345-402 us (1.9-2.2x), this 251-319 us (1.6-2.2x);
      one-way burst, transport alone: previous 135-249 k frames/s, this 346-491 k frames/s.
  Alternatives measured on raw zenoh ping-pong (60 B, p50, bare ~90-100 us): reader thread + queue
  160-180 us; zenoh Callback(indirect=True) + deque + Condition ~145 us; Callback(indirect=False)
  160-230 us and only ~40 k frames/s (every sample takes the GIL from a zenoh thread); try_recv() +
  time.sleep polling 300-400 us (a sleep lasts >= 70 us here); this design ~110 us.
  sys.setswitchinterval(1e-4) changed nothing beyond the noise, before or after: with no Python thread
  on the data path there is no GIL hand-over left to shorten.
- What runs between recv() returning a frame and receive() returning is on the caller's critical
  path (a reply is computed from that frame) and runs with cold caches (see cfstack.link_bench, "Reading the
  ratios"), so it is kept to: the payload, one try_recv() for frames queued behind it, the byte
  counts. Cutting it to that (no kind check, no disarm/_drain() calls, no generator) lowered the
  transport row's p50 by 12 us (median; -19..+7 us) against the previous code in the same runs
  (`cfstack link-bench` paths side by side, 14 runs, shared 2-core VM, load 4-8).
"""

from __future__ import annotations

import atexit
import itertools
import math
import threading
import time
import weakref

import zenoh

from link.transports import zenoh_process
from link.transports.base import Transport
from link.transports.zenoh_session import (
    SESSION_OPTIONS,
    ZenohSettings,
    acquire_session,
    max_sample_bytes,
    release_session,
    zenoh_error_text,
)
from model.errors import UserError

# Bound of the receive buffer (zenoh's FIFO): several seconds of a 1 kHz stream.
DEFAULT_QUEUE_FRAMES = 8192
TRANSPORT_OPTIONS = ("queue_frames", "express")
DEFAULT_EXPRESS = False  # see the module docstring for the measurement behind this
# How long close() waits for the waker thread, which ends as soon as it is told to.
WAKER_JOIN_TIMEOUT_S = 2.0
MATCHING_POLL_S = 0.005

_PUT = zenoh.SampleKind.PUT
_WAKE_TAG = b"cfstack-wake"  # attachment prefix of the waker's DELETE samples
_transport_ids = itertools.count(1)
_OPEN_TRANSPORTS: weakref.WeakSet[ZenohTransport] = weakref.WeakSet()


class _Waker:
    """Ends a receive() blocked in the FIFO's recv() at its deadline: a thread that publishes a
    session-local DELETE sample on the rx key, tagged with the wait's number (see the module docstring).

    The receiving thread arms a wait (arm -> number) and, when a frame came first, disarms it by setting
    `_wait` to None itself (inline on its critical path; a wake already on its way is then stale: woke()
    says no to it). The thread
    sleeps until the armed deadline; re-arming with a later deadline does not wake it (it wakes at the
    earlier one, sees the new deadline and sleeps on), so a wait answered in time costs neither a lock
    nor a thread switch. arm() and _run() share `_wait` and `_sleeping_until` without a lock: arm()
    writes `_wait` before it reads `_sleeping_until`, _run() writes `_sleeping_until` (inf) before it
    reads `_wait`, and the GIL runs them in some interleaving of those program orders, so a wait the
    thread did not see always finds `_sleeping_until` late enough to make arm() notify it."""

    def __init__(self, session: zenoh.Session, key: zenoh.KeyExpr, transport_id: int):
        self._session = session
        self._key = key
        self._tag = _WAKE_TAG + f" {transport_id} ".encode()
        self._condition = threading.Condition()
        self._wait: tuple[int, float] | None = None  # (wait number, deadline), replaced whole
        self._next_number = 1
        self._fired = 0  # the last wait number woken
        self._sleeping_until = math.inf  # when the thread wakes next by itself (inf: never, or not started)
        self._closed = False
        self._thread: threading.Thread | None = None

    def arm(self, timeout_s: float) -> int:
        """Start a wait of `timeout_s`; returns its number (woke() recognises its wake sample)."""
        number = self._next_number
        self._next_number = number + 1
        deadline = time.monotonic() + timeout_s
        self._wait = (number, deadline)
        if deadline < self._sleeping_until:  # the thread would wake too late, or is idle, or not started
            with self._condition:
                if self._thread is None:
                    self._thread = threading.Thread(target=self._run, name=f"zenoh-wake {self._key}",
                                                    daemon=True)
                    self._thread.start()
                self._condition.notify()
        return number

    def woke(self, sample: zenoh.Sample, number: int) -> bool:
        """Is this (non-PUT) sample the wake of wait `number`?"""
        attachment = sample.attachment
        return attachment is not None and attachment.to_bytes() == self._tag + str(number).encode()

    def close(self) -> None:
        with self._condition:
            self._closed = True
            self._condition.notify()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(WAKER_JOIN_TIMEOUT_S)

    def _run(self) -> None:
        with self._condition:
            while not self._closed:
                self._sleeping_until = math.inf  # before reading _wait: see the class docstring
                wait = self._wait
                if wait is None or wait[0] == self._fired:
                    self._condition.wait()
                    continue
                number, deadline = wait
                now = time.monotonic()
                if now < deadline:
                    self._sleeping_until = deadline
                    self._condition.wait(deadline - now)
                    continue
                self._fired = number
                self._condition.release()  # never publish holding the lock arm() may take
                try:
                    self._wake(number)
                finally:
                    self._condition.acquire()

    def _wake(self, number: int) -> None:
        try:
            self._session.delete(self._key, attachment=self._tag + str(number).encode(),
                                 allowed_destination=zenoh.Locality.SESSION_LOCAL)
        except zenoh.ZError:
            pass  # the session closed under us: the blocked recv() has ended anyway


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
        self._id = next(_transport_ids)
        self._session: zenoh.Session | None = None
        self._publisher: zenoh.Publisher | None = None
        self._subscriber: zenoh.Subscriber | None = None
        self._handler = None  # the subscriber's FIFO
        self._waker: _Waker | None = None
        self._max_sample_bytes: int | None = None  # the session's limit (a low-latency one's), set at open
        self._receiving = threading.Lock()  # held by the one thread blocked in the FIFO's recv()

    def open(self) -> None:
        if self.is_open:
            return
        tx_key = _key(self.tx, "tx") if self.tx is not None else None
        rx_key = _key(self.rx, "rx") if self.rx is not None else None
        self._session = acquire_session(self.settings)
        self._max_sample_bytes = max_sample_bytes(self.settings)
        try:
            if tx_key is not None:
                self._publisher = self._session.declare_publisher(
                    tx_key, reliability=zenoh.Reliability.RELIABLE,
                    congestion_control=zenoh.CongestionControl.BLOCK, express=self.express)
            if rx_key is not None:
                self._subscriber = self._session.declare_subscriber(
                    rx_key, zenoh.handlers.FifoChannel(self.capacity))
                self._handler = self._subscriber.handler
                self._waker = _Waker(self._session, rx_key, self._id)
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
        self._undeclare()  # ends a recv() blocked in another thread
        if self._waker is not None:
            self._waker.close()
            self._waker = None
        release_session(self.settings)
        self._session = None

    def send(self, frame: bytes) -> bool:
        publisher = self._publisher  # None unless open with a tx key (close() clears it)
        if publisher is None or not self.is_open:
            return self.stats.record_send(len(frame), False)
        limit = self._max_sample_bytes
        if limit is not None and len(frame) > limit:  # zenoh would lose it and the link with it (zenoh_session)
            raise UserError(f"zenoh key {self.tx}: a {len(frame)} B sample is longer than the {limit} B a "
                            f"low-latency zenoh session sends whole ({_limit_remedy(self.settings)})")
        try:
            publisher.put(frame if type(frame) is bytes else bytes(frame))
        except zenoh.ZError:  # the session was closed under us
            return self.stats.record_send(len(frame), False)
        return self.stats.record_send(len(frame), True)

    def receive(self, timeout_s: float = 0.0) -> list[bytes]:
        handler = self._handler  # None unless open with an rx key (close() clears it)
        if handler is None or not self.is_open:
            return []
        frames = self._drain(handler)
        if not frames and timeout_s > 0:
            if self._receiving.acquire(False):
                try:
                    frames = self._wait_in_recv(handler, self._waker, timeout_s)
                finally:
                    self._receiving.release()
            else:
                frames = self._wait_for_turn(handler, self._waker, timeout_s)
        stats = self.stats
        stats.chunks_received += len(frames)
        for frame in frames:
            stats.bytes_received += len(frame)
        return frames

    def _wait_for_turn(self, handler, waker: _Waker, timeout_s: float) -> list[bytes]:
        """Another thread waits in recv(): wait until it is done, then drain, else wait what is left."""
        deadline = time.monotonic() + timeout_s
        if not self._receiving.acquire(timeout=min(timeout_s, threading.TIMEOUT_MAX)):
            return self._drain(handler)
        try:
            frames = self._drain(handler)
            remaining_s = deadline - time.monotonic()
            if frames or remaining_s <= 0:
                return frames
            return self._wait_in_recv(handler, waker, remaining_s)
        finally:
            self._receiving.release()

    def _wait_in_recv(self, handler, waker: _Waker, timeout_s: float) -> list[bytes]:
        """Block in the FIFO's recv() until a frame comes or the waker ends the wait at its deadline.

        What runs between recv() returning and receive() returning lies on the caller's critical path
        (a reply is usually computed from this frame, and right after a wake-up every operation is slow:
        cold caches), so it is kept short: a sample with a payload is a frame without asking its kind
        (DELETE samples, the waker's included, have empty payloads); one try_recv() tells whether
        more frames are queued behind it."""
        number = waker.arm(timeout_s)
        try:
            while True:
                sample = handler.recv()
                frame = sample.payload.to_bytes()
                if frame or sample.kind == _PUT:
                    break
                if waker.woke(sample, number):
                    return []
                # else: a stale wake, another transport's wake on an overlapping key, a remote DELETE
        except zenoh.ZError:  # closed meanwhile: the subscriber (or its session) is gone
            return []
        finally:
            waker._wait = None  # disarm (see _Waker): a wake already on its way is stale
        try:
            following = handler.try_recv()
        except zenoh.ZError:  # closed right after recv(): the frame taken is still delivered
            return [frame]
        if following is None:
            return [frame]
        frames = [frame]
        frame = following.payload.to_bytes()
        if frame or following.kind == _PUT:
            frames.append(frame)
        frames += self._drain(handler)
        return frames

    def _drain(self, handler) -> list[bytes]:
        """The frames already in the FIFO (at most its capacity, so a flood cannot hold us here)."""
        frames = []
        try:
            for _ in range(self.capacity):
                sample = handler.try_recv()
                if sample is None:
                    break
                frame = sample.payload.to_bytes()
                if frame or sample.kind == _PUT:  # DELETE samples (wakes) have empty payloads
                    frames.append(frame)
        except zenoh.ZError:  # closed from another thread meanwhile
            pass
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

    def _undeclare(self) -> None:
        for entity in (self._subscriber, self._publisher):
            if entity is not None:
                try:
                    entity.undeclare()
                except zenoh.ZError:
                    pass  # already gone with its session
        self._subscriber = None
        self._publisher = None
        self._handler = None


def _limit_remedy(settings: ZenohSettings) -> str:
    """What lifts a low-latency session's sample limit: its config file where one decides the transport
    (the environment variable does not apply then: zenoh_process), else the environment variable."""
    if settings.config_file is not None:
        return f"{settings.config_file} turns on transport/unicast/lowlatency; false there lifts it"
    return f"{zenoh_process.TRANSPORT_ENV}=universal lifts it"


def _key(key: str, role: str) -> zenoh.KeyExpr:
    try:
        return zenoh.KeyExpr(key)
    except zenoh.ZError as err:
        reason = zenoh_error_text(err)
        raise UserError(f"zenoh {role} key '{key}' is not a valid key expression ({reason})") from None


def _close_open_transports() -> None:
    # A thread blocked in a FIFO's recv() or a waker must end before the interpreter does, or it aborts.
    for transport in list(_OPEN_TRANSPORTS):
        transport.close()


atexit.register(_close_open_transports)
