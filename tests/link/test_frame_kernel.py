"""The compiled frame kernel (link/mavlink/_frame_kernel.c) against its Python twins: the encoder of a tick's
messages against codec.py's encoders and Codec._wrap (the same frames, byte for byte, or the same error; and what
it leaves to the Python), and parse_frames against FrameParser._scan (the same frames, fields, counters, pending
bytes and observer calls, on streams of every kind of frame, garbage and damage)."""

from __future__ import annotations

import dataclasses
import enum
import math
import struct

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mav

from link.keys import GROUND_STATION_SYSTEM_ID
from link.mavlink import codec, frame_kernel
from link.mavlink.codec import ActuatorLimits, Codec, FrameParser
from link.mavlink.signing import Signing
from link.messages import AttitudeTarget, ExternalPose, ImuSample, MocapPose, ThrustMoment, TimeSync, TruthState
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
        array = np.array([float(v) for v in values], dtype=np.float32 if rng.random() < 0.2 else np.float64)
        return array if rng.random() < 0.7 else np.repeat(array, 2)[::2]  # or a strided view: no contiguous buffer
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


# --- parse_frames against FrameParser._scan ----------------------------------------------------------------------


def python_parser(monkeypatch, *args) -> FrameParser:
    """A parser made while the kernel is absent: it scans with the Python twin only."""
    with monkeypatch.context() as m:
        m.setattr(frame_kernel, "parse_frames", None)
        return FrameParser(*args)


def raw_frame(msgid: int, payload: bytes, flags: int = 0, system_id: int = 1, seq: int = 0,
              crc_extra: int | None = None, signature: bytes = b"") -> bytes:
    """A MAVLink 2 frame built by hand (any header flags, payload length and CRC_EXTRA)."""
    header = struct.pack("<BBBBBBHB", len(payload), flags, 0, seq, system_id, 1, msgid & 0xFFFF, msgid >> 16)
    extra = mav.mavlink_map[msgid].crc_extra if crc_extra is None else crc_extra
    crc = mav.x25crc(header + payload + bytes([extra])).crc
    return b"\xfd" + header + payload + struct.pack("<H", crc) + signature


def odometry_payload(rng: np.random.Generator, frame_id: int, child_frame_id: int) -> bytes:
    return codec.W_ODOMETRY.unpacker.pack(int(rng.integers(0, 2**40)), *rng.normal(size=13).astype(float),
                                          *(0.0,) * 42, frame_id, child_frame_id, 0, 0, 100)


def random_piece(rng: np.random.Generator, sender: Codec) -> bytes:
    """One frame of a kind the kernel decodes natively, one it hands to a Python decoder, or something damaged."""
    roll = int(rng.integers(16))
    if roll <= 3:  # the kernel's native kinds, as the emulator and the ground station send them
        return sender.encode(random_message_plain(rng, [ImuSample, MocapPose, TruthState, ExternalPose][roll]), 1)
    if roll == 4:  # everything else the codec speaks (its Python decoders, through the kernel)
        return sender.encode(codec.sample_messages()[int(rng.integers(11))], 1)
    if roll == 5:  # truth in another frame convention: unsupported
        return raw_frame(codec.W_ODOMETRY.msgid, odometry_payload(rng, int(rng.integers(0, 3)), 1))
    if roll == 6:  # zero-truncated payloads (IMU samples of zeros) and extended ones
        zeros = sender.encode(ImuSample(float(rng.integers(0, 3)), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)), 1)
        return zeros if rng.random() < 0.5 else raw_frame(mav.MAVLINK_MSG_ID_TIMESYNC, bytes(16) + b"\x03\x04")
    if roll == 7:  # bad header flags, an empty payload, a message the codec does not decode, an unknown id
        return [raw_frame(mav.MAVLINK_MSG_ID_TIMESYNC, b"\x01", flags=0x02),
                raw_frame(mav.MAVLINK_MSG_ID_TIMESYNC, b""),
                raw_frame(mav.MAVLINK_MSG_ID_PING, bytes(14)),
                raw_frame(60000, b"\x01\x02", crc_extra=0)][int(rng.integers(4))]
    if roll == 8:  # signed-flag frames (this parser does not check signatures: delivered as unsigned)
        return raw_frame(mav.MAVLINK_MSG_ID_TIMESYNC, struct.pack("<qq", 3, 4), flags=0x01,
                         signature=bytes(rng.integers(0, 256, 13, dtype=np.uint8)))
    if roll == 9:  # a decoder that hands back None (a heartbeat of an unknown mode) or raises (an infinite yaw)
        unknown_mode = raw_frame(mav.MAVLINK_MSG_ID_HEARTBEAT, struct.pack("<IBBBBB", 99, 2, 0, 0, 3, 3))
        infinite_yaw = raw_frame(codec.W_POSITION.msgid, codec.W_POSITION.unpacker.pack(
            1, *(0.0,) * 9, math.inf, 0.0, codec._POSITION_TYPE_MASK, 1, 0, mav.MAV_FRAME_LOCAL_NED))
        return unknown_mode if rng.random() < 0.5 else infinite_yaw
    frame = bytearray(sender.encode(random_message_plain(rng, ImuSample), 1))
    if roll == 10:  # a flipped bit
        frame[int(rng.integers(len(frame)))] ^= 1 << int(rng.integers(8))
    elif roll == 11:  # cut short
        frame = frame[: int(rng.integers(1, len(frame)))]
    elif roll == 12:  # stray bytes, magic bytes among them
        frame = bytearray(rng.choice([0xFD, 0x00, 0x11, 0xFE], size=int(rng.integers(1, 9))).astype(np.uint8))
    return bytes(frame)


def random_message_plain(rng: np.random.Generator, kind: type):
    """Plain values the kernel's native decoders see in flight (floats, times in range)."""
    t = float(rng.uniform(0.0, 1e4))
    v = [float(x) for x in rng.normal(size=16)]
    if kind is ImuSample:
        return ImuSample(t, tuple(v[0:3]), tuple(v[3:6]))
    if kind is MocapPose:
        return MocapPose(t, int(rng.integers(1, 255)), tuple(v[0:3]), tuple(v[3:7]))
    if kind is ExternalPose:
        return ExternalPose(t, tuple(v[0:3]), tuple(v[3:7]))
    return TruthState(t, tuple(v[0:3]), tuple(v[3:6]), tuple(v[6:10]), tuple(v[10:13]))


def bits(value):
    """A value with every float as its IEEE bits (NaN == NaN), for comparing decoded messages exactly."""
    if isinstance(value, float):
        return ("float", struct.pack("<d", value))
    if isinstance(value, (tuple, list)):
        return tuple(bits(v) for v in value)
    if isinstance(value, enum.Enum):
        return (type(value).__name__, value.value)
    if dataclasses.is_dataclass(value):
        return (type(value).__name__, *(bits(getattr(value, f.name)) for f in dataclasses.fields(value)))
    return (type(value).__name__, value)


@pytest.mark.parametrize("final", [True, False], ids=["datagrams", "stream"])
@pytest.mark.parametrize("with_limits", [True, False], ids=["limits", "no-limits"])
def test_parse_frames_gives_what_the_python_scan_gives(monkeypatch, final, with_limits):
    rng = np.random.default_rng(int(final) + 2 * int(with_limits))
    limits = LIMITS if with_limits else None
    compiled, python = FrameParser(limits), python_parser(monkeypatch, limits)
    assert compiled._kernel is not None and python._kernel is None
    observed = {"compiled": [], "python": []}
    compiled.frame_observer = lambda *header: observed["compiled"].append(header)
    python.frame_observer = lambda *header: observed["python"].append(header)
    senders = [Codec(3, limits=LIMITS), Codec(GROUND_STATION_SYSTEM_ID, limits=LIMITS)]
    delivered = 0
    for _ in range(1500):
        chunk = b"".join(random_piece(rng, senders[int(rng.integers(2))])
                         for _ in range(int(rng.integers(1, 6))))
        if not final and rng.random() < 0.5:  # a stream cuts anywhere
            cut = int(rng.integers(0, len(chunk) + 1))
            pieces = [chunk[:cut], chunk[cut:]]
        else:
            pieces = [chunk]
        for piece in pieces:
            got, expected = compiled.feed_fields(piece, final), python.feed_fields(piece, final)
            assert bits(got) == bits(expected)
            assert compiled.counters.as_dict() == python.counters.as_dict()
            assert compiled._pending == python._pending
            delivered += len(got)
    assert observed["compiled"] == observed["python"] and observed["python"]
    counts = compiled.counters.as_dict()
    # every path was taken: decoded, unsupported, bad lengths and headers, unknown, CRC failures, cut short
    for name in ("frames_ok", "unsupported_messages", "bad_lengths", "bad_headers", "unknown_messages", "crc_failures",
                 "decode_errors"):
        assert counts[name] > 0, name
    assert counts["truncated_frames" if final else "garbage_bytes"] > 0
    assert delivered > 1000


def test_parse_frames_decodes_what_the_sender_meant():
    """Native kinds through the kernel come out as the messages that went in, to float32."""
    sender, parser = Codec(4, limits=LIMITS), FrameParser(LIMITS)
    sent = [ImuSample(1.5, (0.25, -0.5, 9.75), (0.125, 0.0625, -1.0)),
            TruthState(3.0, (1.0, -2.0, 0.5), (0.25, 0.5, -0.75), (1.0, 0.0, 0.0, 0.0), (0.5, -0.25, 1.0))]
    got = [d.message for d in parser.feed(b"".join(sender.encode(m) for m in sent), final=True)]
    assert [type(m) for m in got] == [ImuSample, TruthState]
    for a, b in zip(got, sent, strict=True):
        assert numbers(a) == pytest.approx(numbers(b), rel=1e-6, abs=1e-7)
    pose = FrameParser(LIMITS).feed(Codec(GROUND_STATION_SYSTEM_ID).encode(
        ExternalPose(2.0, (1.0, 2.0, 3.0), (1.0, 0.0, 0.0, 0.0)), 1), final=True)
    assert isinstance(pose[0].message, ExternalPose)  # a mocap frame from the ground station: the vehicle's own pose


def test_signed_parsers_scan_with_the_python():
    assert FrameParser(LIMITS, Signing(bytes(range(32)), link_id=1))._kernel is None


@pytest.mark.parametrize("args", [(), (FrameParser(), b"")])
def test_bad_calls_to_parse_frames_raise_type_error(args):
    with pytest.raises(TypeError):
        frame_kernel.parse_frames(*args)


def test_parse_frames_takes_bytes_only():
    with pytest.raises(TypeError):
        frame_kernel.parse_frames(FrameParser(), bytearray(b"\xfd"), True)


def test_measure_codec_costs_times_the_twins_in_turns():
    costs = codec.measure_codec_costs(n=20, python_twin=True)
    assert set(costs) == {type(m).__name__ for m in codec.sample_messages()}
    assert all(len(values) == 4 and all(v > 0 for v in values) for values in costs.values())
    with pytest.raises(ValueError):
        codec.measure_codec_costs(n=20, signing=True, python_twin=True)


def test_an_error_inside_the_scan_leaves_the_same_counts(monkeypatch):
    """An observer that raises mid-chunk: feed_fields counts it and starts clean, the counts so far kept, in both."""
    chunk = b"".join([Codec(3).encode(TimeSync(0, 1)), raw_frame(mav.MAVLINK_MSG_ID_PING, bytes(14)),
                      Codec(3).encode(TimeSync(0, 2))])
    parsers = [FrameParser(), python_parser(monkeypatch)]
    for parser in parsers:
        parser.frame_observer = lambda *header: 1 / 0
        assert parser.feed_fields(chunk, True) == []
    assert parsers[0].counters.as_dict() == parsers[1].counters.as_dict()
    assert parsers[0].counters.decode_errors == 1 and parsers[0].counters.frames_ok == 1


def test_direct_fields_names_only_classes_whose_init_just_sets_them():
    """The kernel may skip __init__ only where __init__ is the frozen dataclass's own: each field set, in order."""
    assert codec.direct_fields(ImuSample) == ("time_s", "specific_force_flu_mps2", "rate_flu_radps")
    assert codec.direct_fields(MocapPose) == ("time_s", "body_id", "position_enu_m", "attitude_wxyz")
    assert codec.direct_fields(ExternalPose) == ("time_s", "position_enu_m", "attitude_wxyz")
    assert codec.direct_fields(TruthState) == tuple(f.name for f in dataclasses.fields(TruthState))

    @dataclasses.dataclass(frozen=True)
    class Checked:
        time_s: float

        def __post_init__(self):
            raise ValueError

    @dataclasses.dataclass(frozen=True)
    class Derived:
        time_s: float
        twice: float = dataclasses.field(init=False, default=0.0)

    @dataclasses.dataclass(frozen=True)
    class WithInitVar:
        time_s: float
        scale: dataclasses.InitVar[float]

    @dataclasses.dataclass
    class Mutable:
        time_s: float

    for cls in (Checked, Derived, WithInitVar, Mutable, tuple):
        assert codec.direct_fields(cls) is None, cls


def native_frames(rng: np.random.Generator) -> bytes:
    """Frames of the four kinds the kernel makes itself, from a vehicle and from the ground station."""
    vehicle, ground = Codec(3, limits=LIMITS), Codec(GROUND_STATION_SYSTEM_ID, limits=LIMITS)
    frames = [vehicle.encode(random_message_plain(rng, kind), 1) for kind in (ImuSample, MocapPose, TruthState) * 20]
    frames += [ground.encode(random_message_plain(rng, ExternalPose), 1) for _ in range(20)]
    return b"".join(frames)


def test_the_kernel_makes_messages_as_their_init_makes_them(monkeypatch):
    """Made without running __init__, a message is the one __init__ makes: same class, same instance dict (no
    attribute more or less, the same values), equal, same hash, and still frozen."""
    data = native_frames(np.random.default_rng(7))
    compiled, python = FrameParser(LIMITS), python_parser(monkeypatch, LIMITS)
    got = [d.message for d in compiled.feed(data, final=True)]
    expected = [d.message for d in python.feed(data, final=True)]
    assert len(got) == len(expected) == 80
    assert {type(m) for m in got} == {ImuSample, MocapPose, TruthState, ExternalPose}
    for a, b in zip(got, expected, strict=True):
        assert type(a) is type(b) and bits(vars(a)) == bits(vars(b)) and list(vars(a)) == list(vars(b))
        assert a == b and hash(a) == hash(b)
        with pytest.raises(dataclasses.FrozenInstanceError):
            a.time_s = 0.0


NATIVE_MESSAGES = (ImuSample, MocapPose, ExternalPose, TruthState)  # the order configure_parser takes them in


def configure_parser_with(fields: list, messages: tuple = NATIVE_MESSAGES) -> None:
    frame_kernel.configure_parser(codec._dec_imu, codec._dec_mocap, codec._dec_truth, *messages,
                                  GROUND_STATION_SYSTEM_ID, mav.MAV_FRAME_LOCAL_NED, *fields)


def test_without_direct_fields_the_kernel_calls_the_classes(monkeypatch):
    """Configured with None for every message, the kernel calls each class (its __init__ runs) and gives the same
    messages; a wrong field tuple, or fields for a class object.__new__ cannot make, is refused with one error and
    leaves the configuration as it was."""
    data = native_frames(np.random.default_rng(8))
    expected = [d.message for d in FrameParser(LIMITS).feed(data, final=True)]
    direct = [codec.direct_fields(m) for m in NATIVE_MESSAGES]
    calls = []
    original_init = ImuSample.__init__
    monkeypatch.setattr(ImuSample, "__init__", lambda self, *a: (calls.append(a), original_init(self, *a))[1])
    try:
        configure_parser_with([None] * 4)
        got = [d.message for d in FrameParser(LIMITS).feed(data, final=True)]
        with pytest.raises(ValueError, match="message 1's fields must be None or a tuple of 4 names"):
            configure_parser_with([direct[0], ("time_s",), None, None])
        with pytest.raises(ValueError, match="message 0 has fields but is not a class made by object.__new__"):
            configure_parser_with([("a", "b", "c"), None, None, None], (tuple, *NATIVE_MESSAGES[1:]))
        again = [d.message for d in FrameParser(LIMITS).feed(data, final=True)]
    finally:
        configure_parser_with(direct)
    assert bits(got) == bits(expected) == bits(again)
    assert len(calls) == 2 * sum(isinstance(m, ImuSample) for m in expected) == 40
    restored = [d.message for d in FrameParser(LIMITS).feed(data, final=True)]
    assert bits(restored) == bits(expected) and len(calls) == 40  # made directly again: no __init__ ran
