"""The serial transport over a real pseudo-terminal (os.openpty, raw mode): no mocks.

The test plays the far end (a radio modem) on the pty master; the transport opens the slave device.
"""

from __future__ import annotations

import os
import random
import time

import pytest

from link.transports import open_transport

PTY_BAUD = 57600  # nominal on a pty; a common radio-modem rate
MAVLINK2_MAGIC = 0xFD


def mavlink2_frames() -> list[bytes]:
    """Valid MAVLink 2 frames of messages the cfstack schema decodes, made by pymavlink."""
    from pymavlink.dialects.v20 import common as mavlink2

    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    messages = [
        mav.heartbeat_encode(mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_GENERIC, 0, 0,
                             mavlink2.MAV_STATE_STANDBY),
        mav.highres_imu_encode(1_000_000, 0.1, -0.2, -9.81, 0.01, 0.02, 0.03, 0, 0, 0, 0, 0, 0, 0, 0x3F),
        mav.att_pos_mocap_encode(2_000_000, [1.0, 0.0, 0.0, 0.0], 1.0, 2.0, -0.5),
        mav.heartbeat_encode(mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_GENERIC, 0, 0,
                             mavlink2.MAV_STATE_ACTIVE),
    ]
    return [message.pack(mav) for message in messages]


def line_noise(rng: random.Random, size: int) -> bytes:
    """Random bytes without the MAVLink 2 start byte (a false start is tested separately, below)."""
    return bytes(rng.choice([b for b in range(256) if b != MAVLINK2_MAGIC]) for _ in range(size))


def corrupted(frame: bytes) -> bytes:
    """The frame with one payload byte flipped: its CRC no longer matches."""
    damaged = bytearray(frame)
    damaged[12] ^= 0x55
    return bytes(damaged)


def write_in_pieces(fd: int, data: bytes, rng: random.Random) -> None:
    """Write like a radio modem: pieces of random size that cut frames anywhere."""
    position = 0
    while position < len(data):
        piece = data[position:position + rng.randint(1, 40)]
        os.write(fd, piece)
        position += len(piece)


def receive_bytes(transport, expected: int, timeout_s: float = 5.0) -> list[bytes]:
    chunks, deadline = [], time.monotonic() + timeout_s
    while sum(map(len, chunks)) < expected and time.monotonic() < deadline:
        chunks.extend(transport.receive(0.05))
    return chunks


def test_frames_between_garbage_come_through_and_the_parser_recovers_them(pty_pair):
    master, device = pty_pair
    rng = random.Random(7)
    frames = mavlink2_frames()
    stream = (line_noise(rng, 30) + frames[0] + line_noise(rng, 5) + frames[1]
              + corrupted(frames[2]) + line_noise(rng, 17) + frames[2] + frames[3] + line_noise(rng, 9))
    with open_transport(f"serial:{device}:{PTY_BAUD}") as transport:
        write_in_pieces(master, stream, rng)
        chunks = receive_bytes(transport, len(stream))
    assert b"".join(chunks) == stream  # raw bytes, garbage included, in order
    assert transport.stats.bytes_received == len(stream)

    codec = pytest.importorskip("link.mavlink.codec", reason="link.mavlink.codec (FrameParser) not written yet")
    parser = codec.FrameParser()
    decoded = [item for chunk in chunks for item in parser.feed(chunk)]
    assert [item.frame for item in decoded] == frames
    assert parser.counters.crc_failures >= 1  # the damaged copy was seen and refused


def test_frames_sent_reach_the_far_end(pty_pair):
    master, device = pty_pair
    frames = mavlink2_frames()
    with open_transport(f"serial:{device}:{PTY_BAUD}") as transport:
        for frame in frames:
            assert transport.send(frame)
        expected = b"".join(frames)
        received = b""
        deadline = time.monotonic() + 5.0
        while len(received) < len(expected) and time.monotonic() < deadline:
            received += os.read(master, 4096)
    assert received == expected
    assert transport.stats.frames_sent == len(frames)
    assert transport.stats.bytes_sent == len(expected)


def test_vanished_device_neither_raises_nor_spins():
    master, slave = os.openpty()
    device = os.ttyname(slave)
    os.close(slave)
    with open_transport(f"serial:{device}:{PTY_BAUD}") as transport:
        os.close(master)  # the far end hangs up, like a USB radio being unplugged
        started = time.monotonic()
        assert transport.receive(0.2) == [] and transport.receive(0.2) == []
        assert time.monotonic() - started >= 0.35  # waited out the timeouts rather than spinning
        assert transport.send(b"anyone?") is False
        assert transport.stats.send_errors == 1
