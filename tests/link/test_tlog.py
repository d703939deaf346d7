"""link.mavlink.tlog: the record format, read back by pymavlink's own tlog reader, and survival of SIGKILL."""

from __future__ import annotations

import os
import signal
import struct
import subprocess
import sys
import textwrap
import time

os.environ["MAVLINK20"] = "1"  # mavutil picks its dialect from this at import

import pytest  # noqa: E402
from pymavlink import mavutil  # noqa: E402

from link.mavlink.codec import Codec  # noqa: E402
from link.mavlink.signing import Signing  # noqa: E402
from link.mavlink.tlog import TlogWriter, read_tlog  # noqa: E402
from link.messages import Heartbeat, ImuSample, TimeSync, VehicleMode  # noqa: E402
from model.errors import UserError  # noqa: E402


def pymavlink_read(path):
    """Every message of a tlog as pymavlink reads it: (timestamp s, message)."""
    conn = mavutil.mavlink_connection(str(path), dialect="common")
    out = []
    while (msg := conn.recv_match(blocking=False)) is not None:
        if msg.get_type() != "BAD_DATA":
            out.append((msg._timestamp, msg))
    conn.close()
    return out


def test_record_format(tmp_path):
    frame = Codec(1).encode(TimeSync(0, 5))
    path = tmp_path / "a.tlog"
    with TlogWriter(path) as tlog:
        tlog.write(frame, time_s=1_700_000_000.123456)
    data = path.read_bytes()
    assert data[:8] == struct.pack(">Q", 1_700_000_000_123_456) and data[8:] == frame


def test_pymavlink_reads_every_message_and_timestamp(tmp_path):
    codec = Codec(3, 1, signing=Signing(bytes(32)))  # signed frames too: pymavlink skips the check
    path = tmp_path / "flight.tlog"
    written = []
    with TlogWriter(path) as tlog:
        for i in range(200):
            msg = ImuSample(i * 4e-3, (0.0, 0.0, 9.8125), (i, 0.0, 0.0)) if i % 3 else Heartbeat(True)
            stamp = 1_700_000_000.0 + i * 0.004
            tlog.write(codec.encode(msg), time_s=stamp)
            written.append((stamp, msg))
    got = pymavlink_read(path)
    assert len(got) == len(written)
    for (stamp, msg), (their_stamp, theirs) in zip(written, got, strict=True):
        assert their_stamp == pytest.approx(stamp, abs=1e-6)
        assert theirs.get_type() == ("HIGHRES_IMU" if isinstance(msg, ImuSample) else "HEARTBEAT")
        if isinstance(msg, ImuSample):
            assert theirs.time_usec == round(msg.time_s * 1e6)
    ours = read_tlog(path)
    assert len(ours) == len(written)
    for (stamp, msg), (our_stamp, decoded) in zip(written, ours, strict=True):
        assert our_stamp == pytest.approx(stamp, abs=1e-6)
        if isinstance(msg, ImuSample):
            assert decoded.message.time_s == pytest.approx(msg.time_s, abs=1e-6)
            assert decoded.message.specific_force_flu_mps2 == msg.specific_force_flu_mps2  # exact in float32
            assert decoded.message.rate_flu_radps == msg.rate_flu_radps
        else:
            assert decoded.message == msg


def test_default_clock_and_append(tmp_path):
    path = tmp_path / "sub" / "dir" / "x.tlog"
    frame = Codec(1).encode(Heartbeat(False, VehicleMode.IDLE))
    before = time.time()
    with TlogWriter(path) as tlog:
        tlog.write(frame)
    with TlogWriter(path, clock=lambda: 5.0, append=True) as tlog:
        tlog.write(frame)
    records = read_tlog(path)
    assert before - 1e-6 <= records[0][0] <= time.time() and records[1][0] == 5.0


def test_errors(tmp_path):
    tlog = TlogWriter(tmp_path / "c.tlog")
    tlog.close()
    tlog.close()  # idempotent
    with pytest.raises(ValueError, match="closed"):
        tlog.write(b"\xfd")
    (tmp_path / "file").write_text("")
    with pytest.raises(UserError, match="cannot open tlog"):
        TlogWriter(tmp_path / "file" / "x.tlog")


WRITER = textwrap.dedent("""
    import sys
    from link.mavlink.codec import Codec
    from link.messages import ImuSample
    from link.mavlink.tlog import TlogWriter
    codec = Codec(1)
    tlog = TlogWriter(sys.argv[1], clock=lambda: 0.0)
    i = 0
    while True:
        tlog.write(codec.encode(ImuSample(i * 1e-3, (i, 0.0, 9.81), (0.0, 0.0, 0.0))), time_s=1e9 + i)
        i += 1
        if i == 500:
            print("ready", flush=True)
""")


def test_killed_writer_leaves_a_log_readable_to_the_last_whole_frame(tmp_path):
    path = tmp_path / "killed.tlog"
    child = subprocess.Popen([sys.executable, "-c", WRITER, str(path)], stdout=subprocess.PIPE)
    try:
        assert child.stdout.readline().strip() == b"ready"
        time.sleep(0.05)
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=10)
        child.stdout.close()
    size = path.stat().st_size
    ours = read_tlog(path)
    assert len(ours) >= 500
    for i, (stamp, d) in enumerate(ours):  # every record, in order, intact
        assert stamp == 1e9 + i and d.message.specific_force_flu_mps2[0] == pytest.approx(i, rel=1e-6)
    record_len = 8 + len(ours[0][1].frame)
    assert size - len(ours) * record_len < record_len  # at most the record being written is cut
    theirs = pymavlink_read(path)
    assert len(theirs) == len(ours) and theirs[-1][1].xacc == pytest.approx(len(ours) - 1, rel=1e-6)


def test_buffered_writer_holds_records_until_flush_and_close(tmp_path):
    """buffered=True (the ground station's flight loop: one write per tick, after the tick's commands):
    nothing reaches the file before flush(); flush() writes every record in order, byte for byte as the
    unbuffered writer would; close() flushes the rest."""
    frames = [Codec(1).encode(TimeSync(i, i + 1)) for i in range(6)]
    plain_path, buffered_path = tmp_path / "plain.tlog", tmp_path / "buffered.tlog"
    with TlogWriter(plain_path) as plain:
        for i, frame in enumerate(frames):
            plain.write(frame, time_s=10.0 + i)
    buffered = TlogWriter(buffered_path, buffered=True)
    for i, frame in enumerate(frames[:4]):
        buffered.write(frame, time_s=10.0 + i)
    assert buffered_path.stat().st_size == 0
    assert buffered.frames_written == 4  # counted when written, as the unbuffered writer counts
    buffered.flush()
    assert len(read_tlog(buffered_path)) == 4
    for i, frame in enumerate(frames[4:], start=4):
        buffered.write(frame, time_s=10.0 + i)
    buffered.close()
    assert buffered_path.read_bytes() == plain_path.read_bytes()


def test_a_buffered_record_is_the_frame_as_it_was_when_written(tmp_path):
    """Records are packed at flush(): a frame handed over in a buffer the caller reuses (a bytearray)
    must still be logged as it was at write(), and the byte count must be what reaches the file."""
    frame = bytearray(Codec(1).encode(TimeSync(1, 2)))
    original = bytes(frame)
    writer = TlogWriter(tmp_path / "reused.tlog", buffered=True)
    writer.write(frame, time_s=5.0)
    frame[:] = bytes(len(frame))  # the caller's buffer is overwritten before the flush
    writer.close()
    assert (tmp_path / "reused.tlog").read_bytes()[8:] == original
    assert writer.bytes_written == (tmp_path / "reused.tlog").stat().st_size
