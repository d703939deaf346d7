"""link.endpoint: two endpoints over an in-memory pipe: delivery, receive times, statistics against
the known losses of the pipe, signing, tlogs of both directions, and no automatic answers."""

from __future__ import annotations

import pytest

from link.endpoint import Endpoint
from link.mavlink.codec import ActuatorLimits, Codec, FrameParser, sample_messages
from link.mavlink.signing import Signing
from link.mavlink.tlog import TlogWriter, read_tlog
from link.messages import Heartbeat, ImuSample, TimeSync, VehicleMode
from link.stats import TimeSyncTracker
from link.transports.base import Transport
from link.transports.mem import MemTransport

LIMITS = ActuatorLimits(0.6, (0.01, 0.01, 0.002))
KEY = bytes(range(32))


class Pipe(Transport):
    """One end of an in-memory datagram pipe; `drop(n)` decides whether the n-th frame sent is lost."""

    scheme = "fake"

    def __init__(self, inbox: list, outbox: list, drop=lambda n: False):
        super().__init__("pipe")
        self.inbox, self.outbox, self.drop, self.sent = inbox, outbox, drop, 0

    def open(self):
        self.is_open = True

    def close(self):
        self.is_open = False

    def send(self, frame: bytes) -> bool:
        if not self.is_open:
            return False
        if not self.drop(self.sent):
            self.outbox.append(bytes(frame))
        self.sent += 1
        return True

    def receive(self, timeout_s: float = 0.0) -> list[bytes]:
        chunks, self.inbox[:] = list(self.inbox), []
        return chunks


def pipe_pair(drop=lambda n: False):
    a_to_b, b_to_a = [], []
    a, b = Pipe(b_to_a, a_to_b, drop), Pipe(a_to_b, b_to_a)
    a.open()
    b.open()
    return a, b


class Clock:
    def __init__(self, t: float = 0.0):
        self.t = t

    def __call__(self) -> float:
        return self.t


def endpoints(drop=lambda n: False, signing=(None, None), tlogs=(None, None), clock=None, shared=True):
    clock = clock or Clock(1.0)
    ta, tb = pipe_pair(drop)
    ca = Codec(1, 1, LIMITS, signing[0])
    cb = Codec(255, 1, LIMITS, signing[1])
    a = Endpoint(ta, ca, FrameParser(ca), clock=clock, tlog=tlogs[0], shared_clock=shared)
    b = Endpoint(tb, cb, FrameParser(cb), clock=clock, tlog=tlogs[1], shared_clock=shared)
    return a, b, clock


def test_every_message_arrives_with_its_header_and_receive_time():
    a, b, clock = endpoints()
    frames = [a.send(m, target_system=255) for m in sample_messages()]
    clock.t = 2.5
    got = b.receive()
    assert [type(r.message) for r in got] == [type(m) for m in sample_messages()]
    assert all(r.received_s == 2.5 and not r.signed for r in got)
    assert [r.sequence for r in got[:5]] == [0, 1, 2, 0, 3]  # the MocapPose (4th) counts for system 7
    assert got[0].system_id == 1 and got[0].extra["component_id"] == 1
    assert got[0].extra["target_system"] == 255  # ThrustMoment carries its target
    assert got[3].system_id == 7  # MocapPose: the body id is the frame's system id
    assert b.stats.snapshot().rx_frames == len(frames)
    assert b.receive() == []


def test_loss_counted_from_sequence_gaps_matches_the_pipe():
    dropped = {3, 4, 10, 200, 201, 202, 299}
    a, b, _ = endpoints(drop=lambda n: n in dropped)
    for i in range(300):
        a.send(ImuSample(i * 1e-3, (0.0, 0.0, 9.81), (0.0, 0.0, 0.0)))
        if i % 7 == 0:
            b.receive()
    a.send(Heartbeat(True))  # the last lost frame shows only once a later one arrives
    b.receive()
    snap = b.stats.snapshot()
    assert snap.rx_lost == len(dropped)
    assert snap.rx_frames == 301 - len(dropped)
    assert a.stats.snapshot().tx_frames == 301


def test_duplicates_are_delivered_and_flagged():
    a, b, _ = endpoints()
    frame = a.send(Heartbeat(True, VehicleMode.ATTITUDE))
    a.transport.outbox.append(frame)
    first, second = b.receive()
    assert first.message == second.message and "sequence" not in first.extra
    assert second.extra["sequence"] == "duplicate" and b.stats.snapshot().rx_duplicates == 1


def test_frame_age_on_a_shared_clock():
    a, b, clock = endpoints()
    clock.t = 5.0
    a.send(ImuSample(4.98, (0.0, 0.0, 9.81), (0.0, 0.0, 0.0)))
    b.receive()
    assert b.stats.snapshot().age_p50_ms == pytest.approx(20.0, abs=1e-3)


def test_signed_link_and_rejection_of_an_unsigned_peer():
    s = Signing(KEY, 1)
    a, b, _ = endpoints(signing=(s, Signing(KEY, 2)))
    a.send(TimeSync(0, 1))
    (r,) = b.receive()
    assert r.signed
    c, d, _ = endpoints(signing=(None, Signing(KEY, 2)))
    c.send(TimeSync(0, 1))
    assert d.receive() == []
    assert d.stats.snapshot().signature_failures == 1


def test_nothing_is_answered_automatically():
    a, b, _ = endpoints()
    a.send(TimeSync(0, 123))  # a TIMESYNC request
    a.send(Heartbeat(True))
    assert len(b.receive()) == 2
    assert b.stats.snapshot().tx_frames == 0 and a.receive() == []


def test_timesync_reply_gives_rtt_and_offset_through_endpoints():
    clock_a, clock_b = Clock(10.0), Clock(110.0)
    ta, tb = pipe_pair()
    a = Endpoint(ta, Codec(1), clock=clock_a)
    b = Endpoint(tb, Codec(2), clock=clock_b)
    tracker_a, tracker_b = TimeSyncTracker(clock_a, a.stats), TimeSyncTracker(clock_b)
    a.send(tracker_a.request())
    clock_a.t += 0.003
    clock_b.t += 0.003
    (request,) = b.receive()
    b.send(tracker_b.handle(request.message))
    clock_a.t += 0.003
    clock_b.t += 0.003
    (reply,) = a.receive()
    tracker_a.handle(reply.message)
    snap = a.stats.snapshot()
    assert snap.rtt_p50_ms == pytest.approx(6.0, abs=1e-6)
    assert snap.clock_offset_ms == pytest.approx(-100_000.0, abs=1e-6)  # local - remote


def test_tlogs_hold_both_directions(tmp_path):
    clock = Clock(1.0)
    with (TlogWriter(tmp_path / "a.tlog", clock=clock) as log_a,
          TlogWriter(tmp_path / "b.tlog", clock=clock) as log_b):
        a, b, _ = endpoints(tlogs=(log_a, log_b), clock=clock)
        sent_by_a = [a.send(TimeSync(0, i)) for i in range(3)]
        b.receive()
        clock.t = 2.0
        sent_by_b = [b.send(Heartbeat(False, is_ground_station=True))]
        a.receive()
    log_a_frames = [d.frame for _, d in read_tlog(tmp_path / "a.tlog")]
    log_b_frames = [d.frame for _, d in read_tlog(tmp_path / "b.tlog")]
    assert log_a_frames == sent_by_a + sent_by_b
    assert log_b_frames == sent_by_a + sent_by_b
    assert [t for t, _ in read_tlog(tmp_path / "b.tlog")] == [1.0, 1.0, 1.0, 2.0]


def test_refused_sends_are_counted_not_logged(tmp_path):
    with TlogWriter(tmp_path / "x.tlog") as log:
        a, _, _ = endpoints(tlogs=(log, None))
        a.transport.close()
        a.send(TimeSync(0, 1))
    assert a.stats.snapshot().tx_errors == 1 and read_tlog(tmp_path / "x.tlog") == []


def test_datagrams_cut_short_are_dropped_at_once():
    a, b, _ = endpoints()
    frame = a.codec.encode(TimeSync(0, 1))
    b.transport.inbox.extend([frame[:7], a.codec.encode(TimeSync(0, 2))])
    (r,) = b.receive()
    assert r.message == TimeSync(0, 2) and b.parser.counters.truncated_frames == 1


def test_over_the_mem_transport():
    ta = MemTransport("endpoint-test", tx="test/a_to_b", rx="test/b_to_a")
    tb = MemTransport("endpoint-test", tx="test/b_to_a", rx="test/a_to_b")
    clock = Clock(3.0)
    with ta, tb:
        a = Endpoint(ta, Codec(1, 1, LIMITS), clock=clock)
        b = Endpoint(tb, Codec(2, 1, LIMITS), clock=clock)
        sent = [a.send(m) for m in sample_messages()]
        got = b.receive(timeout_s=1.0)
        while len(got) < len(sent):
            more = b.receive(timeout_s=1.0)
            assert more, "mem transport lost frames"
            got += more
    assert [type(r.message) for r in got] == [type(m) for m in sample_messages()]
    assert b.stats.snapshot().rx_lost == 0
