"""link.transports.zenoh_transport details beyond the transport contract: which samples are frames, that a
receive returns every queued frame at once, and that a timed wait ends at its deadline whatever else
arrives. One process, one session connecting nowhere: a transport whose tx key is its rx key hears itself."""

from __future__ import annotations

import threading
import time

import pytest

from link.transports import open_transport
from link.transports.zenoh_session import ZenohSettings, shared_session


@pytest.fixture
def loop(request):
    """A zenoh transport publishing on the key it subscribes to, and the session it uses."""
    key = f"test/zenoh-transport/{request.node.name}"
    with shared_session(ZenohSettings.from_options("")) as session:
        transport = open_transport("zenoh", tx=key, rx=key)
        try:
            yield transport, session, key
        finally:
            transport.close()


def receive_all(transport, count: int, timeout_s: float = 5.0) -> list[bytes]:
    frames: list[bytes] = []
    deadline = time.monotonic() + timeout_s
    while len(frames) < count and time.monotonic() < deadline:
        frames += transport.receive(0.1)
    return frames


def test_deletes_are_not_frames_but_an_empty_put_is(loop):
    transport, session, key = loop
    session.delete(key)  # what a remote DELETE (or another transport's wake) looks like
    assert transport.send(b"")
    session.delete(key, attachment=b"cfstack-wake 0 1")  # someone else's wake on our key
    assert transport.send(b"frame")
    assert receive_all(transport, 2) == [b"", b"frame"]
    assert transport.stats.chunks_received == 2 and transport.stats.bytes_received == len(b"frame")


def test_a_receive_returns_every_queued_frame_at_once(loop):
    transport, _, _ = loop
    frames = [bytes([n]) * (n + 1) for n in range(20)]
    for frame in frames:
        assert transport.send(frame)
    time.sleep(0.3)  # all delivered into the FIFO by now (same session)
    started = time.monotonic()
    assert transport.receive(2.0) == frames
    assert time.monotonic() - started < 0.5  # queued frames do not wait for the timeout


def test_a_wait_ends_at_its_deadline_even_while_foreign_deletes_arrive(loop):
    transport, session, key = loop
    stop = threading.Event()

    def pester() -> None:
        while not stop.wait(0.02):
            session.delete(key)

    thread = threading.Thread(target=pester, daemon=True)
    thread.start()
    try:
        started = time.monotonic()
        assert transport.receive(0.3) == []
        waited = time.monotonic() - started
    finally:
        stop.set()
        thread.join(2.0)
    assert 0.28 <= waited < 1.5  # the deletes neither end the wait early nor keep it going
    assert transport.send(b"after") and receive_all(transport, 1) == [b"after"]
