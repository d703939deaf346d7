"""link.stats: loss/duplicate/reorder accounting against known ground truth, TIMESYNC arithmetic on
simulated clocks with known offset and delays, frame ages, and the snapshot record."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mav

from link.mavlink.codec import Codec, FrameParser
from link.messages import TimeSync
from link.stats import LinkStats, SequenceTracker, TimeSyncTracker


def feed(tracker: SequenceTracker, sequence_numbers, system_id=1, component_id=1):
    return [tracker.observe(system_id, component_id, s % 256) for s in sequence_numbers]


def test_no_gaps_across_the_wrap():
    t = SequenceTracker()
    feed(t, range(200, 700))
    assert (t.lost, t.duplicates, t.reordered, t.unique) == (0, 0, 0, 500)


def test_gap_across_the_wrap_counts_exactly():
    t = SequenceTracker()
    feed(t, [250, 251, 252, 257, 258])  # 253, 254, 255, 0 missing
    assert t.lost == 4


def test_late_frame_uncounts_its_loss_and_counts_as_reordered():
    t = SequenceTracker()
    verdicts = feed(t, [10, 11, 13, 14, 12])
    assert verdicts[-1] == "late" and (t.lost, t.reordered, t.duplicates) == (0, 1, 0)
    verdicts = feed(t, [12, 14])
    assert verdicts == ["duplicate", "duplicate"] and t.duplicates == 2 and t.lost == 0


def test_late_frame_across_the_wrap():
    t = SequenceTracker()
    feed(t, [254, 1, 2, 255, 0])
    assert (t.lost, t.reordered) == (0, 2)


def test_streams_are_separate():
    t = SequenceTracker()
    for s in range(20):
        t.observe(1, 1, s)
        if s % 2 == 0:
            t.observe(1, 2, s // 2)  # its own numbering, no loss
    assert t.lost == 0 and t.duplicates == 0


@pytest.mark.parametrize("seed", range(4))
def test_random_loss_reordering_and_duplication_match_ground_truth(seed):
    rng = np.random.default_rng(seed)
    n = 3000
    sent = np.arange(n)
    kept = sent[rng.random(n) > 0.1]  # 10 % loss
    # local reordering: displace frames by < 40 positions (the stream's first frame stays first)
    rest = kept[1:]
    order = np.argsort(np.arange(len(rest)) + rng.uniform(0, 40, len(rest)))
    arrived = [kept[0], *rest[order]]
    dup_positions = rng.choice(len(arrived), 50, replace=False)
    for pos in sorted(dup_positions, reverse=True):
        arrived.insert(pos + 1, arrived[pos])  # an immediate repeat: unambiguous
    t = SequenceTracker()
    feed(t, arrived)
    last = max(kept)
    truly_lost = int(np.sum(~np.isin(np.arange(kept.min(), last + 1), kept)))
    assert t.lost == truly_lost
    assert t.duplicates == 50
    assert t.unique == len(kept)


def test_timesync_gives_rtt_and_offset_on_known_clocks():
    # local clock L; remote clock R = L + 0.5 s. Uplink delay 10 ms, downlink 30 ms.
    now = {"t": 100.0}
    local = lambda: now["t"]  # noqa: E731
    remote = lambda: now["t"] + 0.5  # noqa: E731
    stats = LinkStats()
    requester = TimeSyncTracker(local, stats)
    responder = TimeSyncTracker(remote)
    request = requester.request()
    assert request.remote_ns == 0 and request.origin_ns == 100_000_000_000
    now["t"] += 0.010
    reply = responder.handle(request)
    assert reply == TimeSync(remote_ns=100_510_000_000, origin_ns=request.origin_ns)
    now["t"] += 0.030
    assert requester.handle(reply) is None
    sample = requester.samples[-1]
    assert sample.rtt_s == pytest.approx(0.040)
    # offset = local - remote = -0.5 s, biased by half the path asymmetry: (10 - 30)/2 ms
    assert sample.offset_s == pytest.approx(-0.5 + (0.030 - 0.010) / 2)
    assert stats.clock_offset_s == pytest.approx(sample.offset_s)


def test_timesync_ignores_replies_to_others_and_a_zero_clock_still_replies():
    tracker = TimeSyncTracker(lambda: 0.0)
    assert tracker.handle(TimeSync(remote_ns=5, origin_ns=12345)) is None
    assert tracker.foreign_replies == 1 and len(tracker.samples) == 0
    assert tracker.answer(TimeSync(0, 9)) == TimeSync(1, 9)  # tc1 = 0 would read as a request


def test_percentiles_of_known_samples():
    stats = LinkStats()
    tracker = TimeSyncTracker(lambda: 0.0, stats)
    for ms in range(1, 101):
        tracker._outstanding[0] = None
        tracker.clock = lambda ms=ms: ms / 1000.0
        tracker.on_reply(TimeSync(remote_ns=1, origin_ns=0))
    snap = stats.snapshot()
    assert snap.rtt_samples == 100
    assert snap.rtt_p50_ms == pytest.approx(np.percentile(np.arange(1, 101), 50))
    assert snap.rtt_p99_ms == pytest.approx(np.percentile(np.arange(1, 101), 99))


def decoded_frames(n=5, system_id=3):
    codec = Codec(system_id)
    parser = FrameParser()
    return [d for i in range(n) for d in parser.feed(codec.encode(TimeSync(0, i)))]


def test_ages_need_a_shared_clock_or_an_offset():
    (d,) = decoded_frames(1)
    unknown = LinkStats(shared_clock=False)
    unknown.record_received(d, received_s=10.0, sample_time_s=9.99)
    assert unknown.snapshot().age_samples == 0
    shared = LinkStats(shared_clock=True)
    shared.record_received(d, received_s=10.0, sample_time_s=9.99)
    assert shared.snapshot().age_p50_ms == pytest.approx(10.0)
    measured = LinkStats()
    measured.offset_s.append(0.0)
    measured._offset_estimate = 0.25  # local clock 250 ms ahead of the sender's
    measured.record_received(d, received_s=10.0, sample_time_s=9.74)
    assert measured.snapshot().age_p50_ms == pytest.approx(10.0)


def test_snapshot_counts_record_and_serialise():
    stats = LinkStats()
    frames = decoded_frames(10)
    for d in frames[:3] + frames[5:]:  # two lost
        stats.record_received(d, 1.0)
    stats.record_received(frames[6], 1.0)  # one duplicate
    for d in frames:
        stats.record_sent(len(d.frame))
    stats.record_sent(10, ok=False)
    snap = stats.snapshot()
    assert (snap.rx_frames, snap.rx_lost, snap.rx_duplicates) == (9, 2, 1)
    assert (snap.tx_frames, snap.tx_errors) == (10, 1)
    assert snap.rx_loss_ratio == pytest.approx(2 / 10)
    assert snap.tx_bytes == sum(len(d.frame) for d in frames)
    assert math.isnan(snap.rtt_p50_ms) and math.isnan(snap.clock_offset_ms)
    row = snap.as_dict()
    assert row["rx_lost"] == 2 and set(row) == {f.name for f in dataclasses.fields(snap)}
    json.dumps(row)  # JSON-able (NaN allowed by Python's json)
    line = snap.summary()
    assert "\n" not in line and "lost 2" in line
    with pytest.raises(dataclasses.FrozenInstanceError):
        snap.rx_lost = 0


def test_parser_counters_and_undelivered_frames():
    codec = Codec(3)
    parser = FrameParser()
    stats = LinkStats()
    stats.attach_parser(parser)
    ping = mav.MAVLink_ping_message(1, 2, 0, 0)
    payload = ping.unpacker.pack(1, 2, 0, 0)
    frames = [codec.encode(TimeSync(0, 1)), codec.frame(ping.id, bytes([ping.crc_extra]), payload),
              codec.encode(TimeSync(0, 2))]
    bad = bytearray(codec.encode(TimeSync(0, 3)))
    bad[-1] ^= 0xFF
    for f in frames + [bytes(bad)]:
        for d in parser.feed(f):
            stats.record_received(d, 0.0)
    snap = stats.snapshot()
    assert snap.rx_lost == 0  # the PING in between was authentic, just not deliverable
    assert snap.unsupported_messages == 1 and snap.crc_failures == 1
    assert snap.rx_bytes == sum(map(len, frames)) + len(bad)


def test_record_frame_is_record_received_from_the_header_fields():
    frames = decoded_frames(300)  # the sequence wraps
    order = frames[:5] + frames[7:9] + frames[6:7] + frames[9:200] + frames[150:151] + frames[210:]
    by_record, by_fields = LinkStats(shared_clock=True), LinkStats(shared_clock=True)
    verdicts = []
    for n, d in enumerate(order):
        received_s, sample_s = 1.0 + 0.01 * n, 0.995 + 0.01 * n
        verdict = by_record.record_received(d, received_s, sample_s)
        assert by_fields.record_frame(d.system_id, d.component_id, d.sequence, len(d.frame), received_s,
                                      sample_s) == verdict
        verdicts.append(verdict)
    assert verdicts.count("late") == 1 and verdicts.count("duplicate") == 1
    assert by_fields.snapshot() == by_record.snapshot()
    assert by_fields.snapshot().rx_lost == 1 + 10  # frame 5, then 200..209
