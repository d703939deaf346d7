"""The compiled deliver kernel (link/_deliver_kernel.c) against its Python twin, link.endpoint.deliver_fields: the
same Received records, the same LinkStats (frame and byte counts, one-way ages, every sequence tracker count and
stream state) and the same tlog (counts, buffered records, or the file), on streams with loss, duplicates, late
frames and wraps; and the same error where a tlog is closed."""

from __future__ import annotations

import dataclasses
import random

import pytest

from link import deliver_kernel
from link.endpoint import deliver_fields
from link.mavlink.codec import ActuatorLimits, Codec, FrameParser
from link.mavlink.tlog import TlogWriter
from link.messages import BatteryStatus, Heartbeat, ImuSample, MocapPose, TruthState, VehicleMode
from link.stats import LinkStats
from model.vehicle import load_vehicle

pytestmark = pytest.mark.skipif(not deliver_kernel.COMPILED, reason="link._deliver_kernel was not built")

LIMITS = ActuatorLimits.from_vehicle(load_vehicle())
RECEIVER_ID = 255


def sample_message(rng: random.Random, t: float):
    """A message of a kind the ground station receives: some with a time_s (an age), some without."""
    q = (1.0, 0.0, 0.0, 0.0)
    return rng.choice([
        ImuSample(t, (rng.uniform(-1, 1), 0.1, 9.81), (0.01, rng.uniform(-1, 1), 0.0)),
        MocapPose(t, 7, (rng.uniform(-2, 2), 1.0, 0.5), q),
        TruthState(t, (1.0, rng.uniform(-2, 2), 0.5), (0.1, 0.0, 0.0), q, (0.0, 0.0, 0.1)),
        Heartbeat(True, VehicleMode.ATTITUDE),
        BatteryStatus(3.9, 80, rng.randrange(65536), 12.0),
    ])


def damaged_stream(seed: int, n: int = 1500) -> list[list[tuple]]:
    """The parser's fields of a radio's datagrams from two vehicles, with frames lost (runs up to 300 long,
    past the sequence's wrap), repeated and delivered late: one list of fields per datagram."""
    rng = random.Random(seed)
    senders = [Codec(system_id=sid, limits=LIMITS) for sid in (1, 2)]
    frames = [senders[rng.randrange(2)].encode(sample_message(rng, 0.002 * k), RECEIVER_ID) for k in range(n)]
    wire: list[bytes] = []
    k = 0
    while k < len(frames):
        roll = rng.random()
        if roll < 0.05:
            k += rng.choice((1, 2, 5, 127, 129, 300))  # lost
            continue
        wire.append(frames[k])
        if roll < 0.10:
            wire.append(frames[k])  # repeated
        elif roll < 0.15 and len(wire) > 3:
            wire.insert(len(wire) - rng.randrange(2, 4), frames[k])  # late
        k += 1
    parser = FrameParser(Codec(system_id=RECEIVER_ID, limits=LIMITS))
    return [parser.feed_fields(chunk, True) for chunk in wire]


class CountingClock:
    """A tlog clock that gives 1, 2, 3... : the twins must call it equally often, in the same order."""

    def __init__(self):
        self.calls = 0

    def __call__(self) -> float:
        self.calls += 1
        return float(self.calls)


def stats_state(stats: LinkStats) -> dict:
    seq = stats.sequences
    streams = {key: (newest, sorted(missing), list(order)) for key, (newest, missing, order) in seq._streams.items()}
    return {"rx_frames": stats.rx_frames, "rx_frame_bytes": stats.rx_frame_bytes, "age_s": list(stats.age_s),
            "lost": seq.lost, "duplicates": seq.duplicates, "reordered": seq.reordered, "unique": seq.unique,
            "streams": streams}


def run(deliver, datagrams, tmp_path, name: str, *, tlog_kind: str, shared_clock: bool, offset_s):
    stats = LinkStats(shared_clock=shared_clock)
    stats._offset_estimate = offset_s
    clock = CountingClock()
    tlog = None if tlog_kind == "none" else TlogWriter(tmp_path / f"{name}.tlog", clock,
                                                       buffered=tlog_kind == "buffered")
    out: list = []
    for i, fields in enumerate(datagrams):
        deliver(fields, stats, tlog, 10.0 + 0.002 * i, out)
    logged = None
    if tlog is not None:
        logged = (tlog.frames_written, tlog.bytes_written, list(tlog._buffer or []))
        tlog.close()
        logged += ((tmp_path / f"{name}.tlog").read_bytes(),)
    return out, stats_state(stats), logged, clock.calls


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize(("tlog_kind", "shared_clock", "offset_s"), [
    ("buffered", True, None), ("buffered", False, None), ("unbuffered", False, -0.0123), ("none", True, 0.004)])
def test_the_kernel_delivers_what_the_python_delivers(tmp_path, seed, tlog_kind, shared_clock, offset_s):
    datagrams = damaged_stream(seed)
    python = run(deliver_fields, datagrams, tmp_path, "python", tlog_kind=tlog_kind, shared_clock=shared_clock,
                 offset_s=offset_s)
    kernel = run(deliver_kernel.deliver_fields, datagrams, tmp_path, "kernel", tlog_kind=tlog_kind,
                 shared_clock=shared_clock, offset_s=offset_s)
    assert kernel == python
    received, state, _, _ = python
    verdicts = [rx.extra.get("sequence", "new") for rx in received]
    # the stream was damaged in every way the tracker tells apart, so both paths of the kernel ran
    assert {"new", "duplicate", "late"} <= set(verdicts)
    assert state["lost"] > 0 and state["reordered"] > 0
    assert state["unique"] + state["duplicates"] == len(received) == state["rx_frames"]
    # an age for each frame that has a time_s, once the clocks give an offset
    timed = sum(hasattr(rx.message, "time_s") for rx in received)
    assert len(state["age_s"]) == (0 if offset_s is None and not shared_clock else timed)


def test_an_age_is_receive_time_minus_sample_time_minus_offset():
    """The arithmetic of LinkStats' definition, from the kernel (not just equal to the twin's)."""
    fields = FrameParser(Codec(system_id=RECEIVER_ID, limits=LIMITS)).feed_fields(
        Codec(system_id=1, limits=LIMITS).encode(ImuSample(2.5, (0.0, 0.0, 9.81), (0.0, 0.0, 0.0)), RECEIVER_ID),
        True)
    stats = LinkStats()
    stats._offset_estimate = 0.25
    out: list = []
    deliver_kernel.deliver_fields(fields, stats, None, 3.0, out)
    assert list(stats.age_s) == [3.0 - 2.5 - 0.25]
    assert out[0].received_s == 3.0 and out[0].system_id == 1 and out[0].message.time_s == 2.5


def test_a_message_time_that_is_not_a_float_gets_python_arithmetic():
    """An int time (exact in Python) is left to Python's own subtraction, in both twins."""
    fields = FrameParser(Codec(system_id=RECEIVER_ID, limits=LIMITS)).feed_fields(
        Codec(system_id=1, limits=LIMITS).encode(ImuSample(2.0, (0.0, 0.0, 9.81), (0.0, 0.0, 0.0)), RECEIVER_ID),
        True)
    with_int_time = [(dataclasses.replace(fields[0][0], time_s=2), *fields[0][1:])]
    ages = []
    for deliver in (deliver_fields, deliver_kernel.deliver_fields):
        stats = LinkStats(shared_clock=True)
        deliver(with_int_time, stats, None, 10**17 + 1, [])
        ages.append(list(stats.age_s))
    assert ages[0] == ages[1] == [10**17 + 1 - 2 - 0.0]


def test_a_closed_tlog_raises_the_same_after_the_same_frames(tmp_path):
    datagrams = damaged_stream(4, n=20)
    fields = [f for chunk in datagrams for f in chunk]
    outcomes = []
    for name, deliver in (("python", deliver_fields), ("kernel", deliver_kernel.deliver_fields)):
        stats, tlog = LinkStats(shared_clock=True), TlogWriter(tmp_path / name / "link.tlog", CountingClock(),
                                                               buffered=True)
        tlog.close()
        out: list = []
        with pytest.raises(ValueError, match="tlog is closed") as err:
            deliver(fields, stats, tlog, 1.0, out)
        outcomes.append((str(err.value).replace(name, ""), out, stats_state(stats)))
    assert outcomes[0] == outcomes[1]
    assert outcomes[0][2]["rx_frames"] == 1  # the first frame was counted before its tlog write failed


@pytest.mark.parametrize("args", [
    ([("not", "nine")], LinkStats(), None, 1.0, []),
    ((), LinkStats(), None, 1.0, []),
    ([], LinkStats(), None, 1.0, None),
])
def test_bad_calls_raise_type_error(args):
    with pytest.raises(TypeError):
        deliver_kernel.deliver_fields(*args)
