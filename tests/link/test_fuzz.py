"""Property tests of link.mavlink.codec.FrameParser on hostile input (hypothesis, derandomized for CI).

Properties, for every input: feed() never raises; every delivered frame is byte-for-byte a frame that
was encoded; genuine frames behind garbage, truncated or corrupted frames are still found; and every
byte is accounted for: bytes_in == garbage_bytes + valid_frame_bytes + pending bytes.
About 10,000 cases in all.
"""

from __future__ import annotations

import math

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from link.mavlink.codec import ActuatorLimits, Codec, FrameParser, sample_messages
from link.mavlink.signing import Signing
from link.messages import ImuSample, MocapPose, TimeSync

LIMITS = ActuatorLimits(0.6, (0.01, 0.01, 0.002))
KEY = bytes(range(32))
FUZZ = settings(derandomize=True, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def build_pool(signing: bool) -> list[bytes]:
    codec = Codec(9, 1, LIMITS, Signing(KEY, 1) if signing else None)
    messages = sample_messages() + [
        ImuSample(0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)),  # heavily zero-truncated
        ImuSample(1e6, (math.nan, math.inf, -1.0), (1e30, -1e-30, 0.0)),
        MocapPose(3.0, 200, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0)),
        TimeSync(2**63 - 1, -(2**63)),
    ]
    return [codec.encode(m) for m in messages * 3]  # several sequence numbers


POOL = build_pool(signing=False)
SIGNED_POOL = build_pool(signing=True)  # encoded once: timestamps increase along the pool


def new_parser(signed: bool = False) -> FrameParser:
    # a receiver clock far in the past accepts every timestamp of the pool as a new stream
    return FrameParser(LIMITS, Signing(KEY, 0, clock=lambda: 1.5e9) if signed else None)


def feed_in_chunks(parser: FrameParser, data: bytes, cuts: list[int], final: bool = True) -> list[bytes]:
    """Feed `data` split at `cuts` (stream semantics), then mark the end; the delivered frames."""
    out = []
    edges = sorted({min(c, len(data)) for c in cuts} | {0, len(data)})
    for a, b in zip(edges, edges[1:], strict=False):
        out.extend(d.frame for d in parser.feed(data[a:b]))
    if final:
        out.extend(d.frame for d in parser.feed(b"", final=True))
    return out


def assert_accounted(parser: FrameParser) -> None:
    c = parser.counters
    assert c.bytes_in == c.garbage_bytes + c.valid_frame_bytes + parser.pending_bytes
    assert c.decode_errors == 0


cuts_strategy = st.lists(st.integers(0, 4000), max_size=6)


@settings(FUZZ, max_examples=2500)
@given(data=st.binary(max_size=600), cuts=cuts_strategy)
def test_random_bytes(data, cuts):
    parser = new_parser()
    delivered = feed_in_chunks(parser, data, cuts)
    assert set(delivered) <= set(POOL)  # in practice empty: random bytes are no frame
    assert_accounted(parser)
    assert parser.pending_bytes == 0


@settings(FUZZ, max_examples=2500)
@given(
    items=st.lists(st.tuples(st.integers(0, len(POOL) - 1), st.binary(max_size=32)), max_size=6),
    tail=st.binary(max_size=32),
    cuts=cuts_strategy,
)
def test_frames_interleaved_with_garbage_all_arrive_in_order(items, tail, cuts):
    frames = [POOL[i] for i, _ in items]
    data = b"".join(garbage + POOL[i] for i, garbage in items) + tail
    parser = new_parser()
    delivered = feed_in_chunks(parser, data, cuts)
    assert delivered == frames
    assert_accounted(parser)


@settings(FUZZ, max_examples=1500)
@given(index=st.integers(0, len(POOL) - 1), keep=st.integers(0, 300), then=st.integers(0, len(POOL) - 1),
       as_datagrams=st.booleans())
def test_truncated_frame_then_a_whole_one(index, keep, then, as_datagrams):
    cut = POOL[index][:keep % len(POOL[index])]
    parser = new_parser()
    if as_datagrams:  # each chunk is a whole datagram: the cut frame is dropped at once
        delivered = [d.frame for chunk in (cut, POOL[then]) for d in parser.feed(chunk, final=True)]
    else:  # a stream: the cut frame's bytes are followed by the next frame's
        delivered = feed_in_chunks(parser, cut + POOL[then], [len(cut)])
    assert delivered == [POOL[then]]
    assert_accounted(parser)


def flip(frame: bytes, bits: list[int]) -> bytes:
    out = bytearray(frame)
    for bit in bits:
        out[(bit // 8) % len(out)] ^= 1 << (bit % 8)
    return bytes(out)


@settings(FUZZ, max_examples=2500)
@given(index=st.integers(0, len(POOL) - 1), bits=st.lists(st.integers(0, 8 * 300), min_size=1, max_size=3),
       then=st.integers(0, len(POOL) - 1), cuts=cuts_strategy)
def test_bit_flipped_frames_are_never_delivered_altered(index, bits, then, cuts):
    corrupted = flip(POOL[index], bits)
    parser = new_parser()
    delivered = feed_in_chunks(parser, corrupted + POOL[then], cuts)
    assert set(delivered) <= set(POOL)
    assert delivered[-1:] == [POOL[then]]  # the clean frame behind is found
    if corrupted != POOL[index]:
        assert delivered == [POOL[then]]
        assert parser.counters.dropped_frames + parser.counters.garbage_bytes > 0
    assert_accounted(parser)


@settings(FUZZ, max_examples=1000)
@given(index=st.integers(0, len(SIGNED_POOL) - 1), bits=st.lists(st.integers(0, 8 * 320), min_size=1,
       max_size=4), cuts=cuts_strategy)
def test_signed_frames_altered_anywhere_are_rejected(index, bits, cuts):
    frame = SIGNED_POOL[index]
    corrupted = flip(frame, bits)
    parser = new_parser(signed=True)
    delivered = feed_in_chunks(parser, corrupted, cuts)
    assert delivered == ([frame] if corrupted == frame else [])
    assert_accounted(parser)


@settings(FUZZ, max_examples=150)
@given(seed_bytes=st.binary(min_size=16, max_size=64), size=st.integers(10_000, 70_000),
       index=st.integers(0, len(POOL) - 1), cuts=cuts_strategy)
def test_oversize_garbage_does_not_grow_the_buffer(seed_bytes, size, index, cuts):
    garbage = (seed_bytes * (size // len(seed_bytes) + 1))[:size]
    parser = new_parser()
    delivered = []
    for start in range(0, size, 4096):  # arrives in chunks, as from a serial port
        delivered.extend(d.frame for d in parser.feed(garbage[start:start + 4096]))
        assert parser.pending_bytes < 300  # never more than one incomplete frame is held
    delivered.extend(feed_in_chunks(parser, POOL[index], cuts))
    assert delivered == [POOL[index]]
    assert_accounted(parser)
