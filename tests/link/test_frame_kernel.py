"""The compiled encoder of a tick's messages (link/mavlink/_frame_kernel.c) against its Python twin, codec.py's
encoders and Codec._wrap: the same frames, byte for byte, or the same error; and what it leaves to the Python."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from link.mavlink import codec, frame_kernel
from link.mavlink.codec import ActuatorLimits, Codec, FrameParser
from link.mavlink.signing import Signing
from link.messages import AttitudeTarget, ExternalPose, ImuSample, MocapPose, ThrustMoment, TruthState
from model.vehicle import load_vehicle

pytestmark = pytest.mark.skipif(not frame_kernel.COMPILED, reason="link.mavlink._frame_kernel was not built")

LIMITS = ActuatorLimits.from_vehicle(load_vehicle())
KINDS = (ImuSample, MocapPose, ExternalPose, TruthState, ThrustMoment, AttitudeTarget)
FLOAT32_MAX = float(np.finfo(np.float32).max)


def python_codec(monkeypatch, *args, **kwargs) -> Codec:
    """A codec made while the kernel is absent: it runs the Python twin only."""
    with monkeypatch.context() as m:
        m.setattr(frame_kernel, "encode_frame", None)
        return Codec(*args, **kwargs)


def outcome(codec_: Codec, msg, target: int):
    """The frame, or the error's type and text."""
    try:
        return codec_.encode(msg, target)
    except Exception as err:  # noqa: BLE001 - compared as they are
        return type(err), str(err)


def random_number(rng: np.random.Generator):
    """Mostly plain floats of every magnitude; now and then what a float32 cannot hold, a non-finite value, a
    signed zero, or a number that is not a Python float (an int, a numpy float32 or float64)."""
    roll = rng.random()
    if roll < 0.70:
        return float(rng.normal() * 10.0 ** rng.integers(-8, 6))
    return [0.0, -0.0, math.nan, math.inf, -math.inf, 3.5e38, -1e39, 1e-45, FLOAT32_MAX, 2, np.float32(0.5),
            np.float64(-1.25)][rng.integers(12)]


def random_vector(rng: np.random.Generator, n: int):
    """n numbers as a tuple, a list, a float64 array; now and then of another length, or a float32 array."""
    values = [random_number(rng) if rng.random() < 0.2 else float(rng.normal()) for _ in range(n)]
    roll = rng.random()
    if roll < 0.05:
        values = values + [float(rng.normal())]  # longer: indexed fields ignore the rest, unpacked ones raise
    elif roll < 0.08:
        values = values[:-1]
    if rng.random() < 0.15:
        return np.array([float(v) for v in values], dtype=np.float32 if rng.random() < 0.2 else np.float64)
    return list(values) if rng.random() < 0.2 else tuple(values)


def random_time(rng: np.random.Generator):
    roll = rng.random()
    if roll < 0.8:
        return float(rng.uniform(0.0, 1e5))
    if roll < 0.9:  # exact halves of the unit: Python's round() takes them to the even neighbour
        return float(rng.integers(0, 1000)) + 0.5e-6 if rng.random() < 0.5 else (rng.integers(0, 1000) + 0.5) / 1e3
    return [-1e-6, -0.0, math.nan, math.inf, 2e13, 5e6, 4294967.2955, 7, np.float64(0.25)][rng.integers(9)]


def random_message(rng: np.random.Generator, kind: type):
    t = random_time(rng)
    if kind is ImuSample:
        return ImuSample(t, random_vector(rng, 3), random_vector(rng, 3))
    if kind is MocapPose:
        return MocapPose(t, int(rng.integers(1, 256)), random_vector(rng, 3), random_vector(rng, 4))
    if kind is ExternalPose:
        return ExternalPose(t, random_vector(rng, 3), random_vector(rng, 4))
    if kind is TruthState:
        return TruthState(t, random_vector(rng, 3), random_vector(rng, 3), random_vector(rng, 4), random_vector(rng, 3))
    if kind is ThrustMoment:
        return ThrustMoment(t, random_number(rng), random_vector(rng, 3))
    return AttitudeTarget(t, random_number(rng), random_vector(rng, 4), random_vector(rng, 3))


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")  # numpy's, on values too large on purpose
@pytest.mark.parametrize("kind", KINDS, ids=lambda k: k.__name__)
def test_kernel_frames_are_the_pythons_byte_for_byte(monkeypatch, kind):
    rng = np.random.default_rng(KINDS.index(kind))
    compiled, python = Codec(7, limits=LIMITS), python_codec(monkeypatch, 7, limits=LIMITS)
    assert compiled._kernel is not None and python._kernel is None
    taken = 0
    for _ in range(3000):
        msg = random_message(rng, kind)
        target = int(rng.integers(0, 256)) if rng.random() < 0.97 else [256, -1, True][rng.integers(3)]
        source = msg.body_id if kind is MocapPose else 7  # a mocap frame's source is its body
        by_kernel = frame_kernel.encode_frame(codec.KERNEL_KINDS[kind], msg, compiled._sequence.get(source, 0),
                                              source, 1, target, compiled._limit_values)
        expected = outcome(python, msg, target)
        assert outcome(compiled, msg, target) == expected, msg
        if by_kernel is not None:
            taken += 1
            assert by_kernel == expected, msg
    assert compiled._sequence == python._sequence
    assert taken > 1500  # most messages went through the kernel, not its hand-back


def test_frames_of_the_kernel_decode_to_the_message():
    """The round trip through the parser: what the kernel packs is what the fields say."""
    parser = FrameParser(LIMITS)
    sent = [ImuSample(1.5, (0.25, -0.5, 9.75), (0.125, 0.0625, -1.0)),
            MocapPose(2.0, 3, (1.0, 2.0, 3.0), (0.5, 0.5, 0.5, 0.5)),
            TruthState(3.0, (1.0, -2.0, 0.5), (0.25, 0.5, -0.75), (1.0, 0.0, 0.0, 0.0), (0.5, -0.25, 1.0)),
            ThrustMoment(4.0, LIMITS.max_thrust_n / 2, tuple(m / 4 for m in LIMITS.max_moment_nm)),
            AttitudeTarget(5.0, LIMITS.max_thrust_n / 4, (1.0, 0.0, 0.0, 0.0), (0.5, 0.25, -0.125))]
    compiled = Codec(9, limits=LIMITS)
    for msg in sent:
        source = msg.body_id if isinstance(msg, MocapPose) else 9
        frame = frame_kernel.encode_frame(codec.KERNEL_KINDS[type(msg)], msg, 0, source, 1, 1,
                                          compiled._limit_values)
        assert frame is not None
        (decoded,) = parser.feed(frame, final=True)
        assert type(decoded.message) is type(msg)
        # float32 on the wire, and the quaternion's conversion multiplies by sqrt(1/2) both ways
        assert numbers(decoded.message) == pytest.approx(numbers(msg), rel=1e-6, abs=1e-7)


def numbers(msg) -> list[float]:
    """A message's numbers in field order, vectors flattened."""
    out = []
    for field in dataclasses.fields(msg):
        value = getattr(msg, field.name)
        out.extend(value if isinstance(value, tuple) else [value])
    return out


@pytest.mark.parametrize("msg, limits, target", [
    (ImuSample(1, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)), None, 0),  # an int time: Python's arithmetic is exact
    (ImuSample(1.0, (0.0, 0, 0.0), (0.0, 0.0, 0.0)), None, 0),  # an int in a vector
    (ImuSample(1.0, np.zeros(3, np.float32), (0.0, 0.0, 0.0)), None, 0),  # float32 arithmetic
    (ImuSample(1.0, (0.0, 0.0), (0.0, 0.0, 0.0)), None, 0),  # unpacking raises
    (ImuSample(1.0, (0.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0)), None, 0),
    (ImuSample(-1e-6, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)), None, 0),  # struct raises for a negative time
    (ImuSample(math.nan, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)), None, 0),
    (ImuSample(2e13, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)), None, 0),  # beyond 2^64 us
    (ImuSample(1.0, (1e39, 0.0, 0.0), (0.0, 0.0, 0.0)), None, 0),  # too large for a float32
    (MocapPose(1.0, 1, (0.0, 0.0), (1.0, 0.0, 0.0, 0.0)), None, 0),  # indexing raises
    (AttitudeTarget(4294967.2955, 0.1, (1.0, 0.0, 0.0, 0.0)), LIMITS, 0),  # beyond 2^32 ms
    (ThrustMoment(1.0, 0.1, (0.0, 0.0, 0.0)), None, 0),  # no limits
    (ThrustMoment(1.0, 0.1, (0.0, 0.0, 0.0)), LIMITS, 256),  # no such target system
    (ThrustMoment(1.0, 0.1, (0.0, 0.0, 0.0)), LIMITS, True),
])
def test_the_kernel_hands_back_what_the_python_might_not_do_alike(msg, limits, target):
    values = None if limits is None else codec._limit_values(limits)
    assert frame_kernel.encode_frame(codec.KERNEL_KINDS[type(msg)], msg, 0, 1, 1, target, values) is None


def test_limits_that_are_not_floats_are_left_to_the_python(monkeypatch):
    int_limits = ActuatorLimits(max_thrust_n=1, max_moment_nm=(1, 1, 1))
    assert codec._limit_values(int_limits) is None
    msg = ThrustMoment(1.0, 0.5, (0.25, 0.125, -0.5))
    assert Codec(3, limits=int_limits).encode(msg) == python_codec(monkeypatch, 3, limits=int_limits).encode(msg)


def test_signed_frames_are_the_pythons():
    signing = Signing(bytes(range(32)), link_id=1)
    assert Codec(1, limits=LIMITS, signing=signing)._kernel is None


@pytest.mark.parametrize("args", [(), (0, None, 0, 1, 1, 0), (0, None, 0, 1, 1, 0, None, 0)])
def test_bad_calls_raise_type_error(args):
    with pytest.raises(TypeError):
        frame_kernel.encode_frame(*args)
