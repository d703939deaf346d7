"""Bare zenoh: a raw publisher and FIFO subscriber with no codec, statistics or framing - the baseline that
`cfstack link-bench` measures the zenoh transport and the whole link against.

Takes in: an open zenoh.Session (link.transports.zenoh_session) and the keys to publish and subscribe on.
Gives out: BareZenoh (send bytes, blocking recv, wait for subscribers, a guard that turns a stuck recv into a
one-line UserError), and ZENOH_ERRORS, the exception types a zenoh call may raise, for callers outside link/
(which do not import zenoh).
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Iterator

import zenoh

from link.transports.zenoh_transport import DEFAULT_EXPRESS, DEFAULT_QUEUE_FRAMES, MATCHING_POLL_S
from model.errors import UserError

ZENOH_ERRORS: tuple[type[Exception], ...] = (zenoh.ZError,)


class BareZenoh:
    """A raw zenoh publisher and FIFO subscriber on a session; recv() blocks (no timeout in zenoh)."""

    def __init__(self, session: zenoh.Session, tx_key: str, rx_key: str):
        self.publisher = session.declare_publisher(
            tx_key, reliability=zenoh.Reliability.RELIABLE, congestion_control=zenoh.CongestionControl.BLOCK,
            express=DEFAULT_EXPRESS)
        self.subscriber = session.declare_subscriber(rx_key, zenoh.handlers.FifoChannel(DEFAULT_QUEUE_FRAMES))
        self._handler = self.subscriber.handler

    def send(self, payload: bytes) -> None:
        self.publisher.put(payload)

    def recv(self) -> bytes:
        return self._handler.recv().payload.to_bytes()

    def wait_for_subscribers(self, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while not self.publisher.matching_status.matching:
            if time.monotonic() >= deadline:
                return False
            time.sleep(MATCHING_POLL_S)
        return True

    @contextlib.contextmanager
    def guard(self, limit_s: float) -> Iterator[None]:
        """Undeclare the subscriber if the block takes longer than `limit_s`: a blocked recv() then raises
        instead of hanging for ever (zenoh's recv has no timeout)."""
        timer = threading.Timer(limit_s, self.subscriber.undeclare)
        timer.daemon = True
        timer.start()
        try:
            yield
        except zenoh.ZError:
            raise UserError(f"bare zenoh got no reply within {limit_s:.0f} s") from None
        finally:
            timer.cancel()

    def close(self) -> None:
        for entity in (self.subscriber, self.publisher):
            with contextlib.suppress(zenoh.ZError):
                entity.undeclare()
