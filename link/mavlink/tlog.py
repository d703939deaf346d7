"""Telemetry logs (.tlog): every MAVLink frame of a link, time-stamped, in the format QGroundControl,
MAVProxy and pymavlink's `mavutil.mavlink_connection("x.tlog")` read.

Takes in: frames (bytes) and, per frame, the time it crossed the link (seconds; by default the writer's
clock, unix-epoch time.time()).
Gives out: a file of records `timestamp (8 bytes, big-endian unsigned, microseconds) | frame`;
`read_tlog` gives back (time_s, Decoded) pairs through a codec.FrameParser.

Each record goes to the operating system in one os.write call as soon as it is written (no Python-level
buffering), so a process that is killed loses at most the record being written; surviving a power loss
would need `fsync=True` (an fsync per frame: slow). With `buffered=True` records wait in memory until
`flush()` (or close), which the owner calls at a point of its choosing - the ground station's flight loop
once per tick, after the tick's commands are sent - so a killed process loses at most the records since
the last flush, and the writes leave the loop's critical path.
"""

from __future__ import annotations

import os
import struct
import time
from collections.abc import Callable
from pathlib import Path

from link.mavlink.codec import (
    IFLAG_SIGNED,
    MAGIC_V2,
    MIN_FRAME_LEN,
    SIGNATURE_BLOCK_LEN,
    Decoded,
    FrameParser,
)
from model.errors import UserError

_TIMESTAMP = struct.Struct(">Q")
RECORD_HEADER_LEN = _TIMESTAMP.size  # the bytes a record adds to its frame


def _record(stamp_s: float, frame: bytes) -> bytes:
    """One tlog record: the time (microseconds, big-endian) and the frame."""
    return _TIMESTAMP.pack(max(0, int(round(stamp_s * 1e6)))) + bytes(frame)


class TlogWriter:
    """Appends time-stamped frames to a .tlog file; a context manager. `clock()` returns seconds."""

    def __init__(self, path: str | Path, clock: Callable[[], float] = time.time, *, fsync: bool = False,
                 append: bool = False, buffered: bool = False):
        self.path = Path(path)
        self.clock = clock
        self.fsync = fsync
        self._buffer: list[tuple[float, bytes]] | None = [] if buffered else None  # not yet flushed
        self.frames_written = 0
        self.bytes_written = 0
        self._fd: int | None = None
        flags = os.O_WRONLY | os.O_CREAT | (os.O_APPEND if append else os.O_TRUNC)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._fd = os.open(self.path, flags, 0o644)
        except OSError as err:
            raise UserError(f"{self.path}: cannot open tlog for writing ({err.strerror})") from None

    def write(self, frame: bytes, time_s: float | None = None) -> None:
        """Append one frame stamped `time_s` (default: now on the writer's clock)."""
        if self._fd is None:
            raise ValueError(f"{self.path}: tlog is closed")
        stamp_s = self.clock() if time_s is None else time_s
        self.frames_written += 1
        self.bytes_written += RECORD_HEADER_LEN + len(frame)
        if self._buffer is not None:  # packed at flush(), off the caller's critical path
            self._buffer.append((stamp_s, frame if type(frame) is bytes else bytes(frame)))  # a copy if mutable
        else:
            self._write(_record(stamp_s, frame))

    def flush(self) -> None:
        """Write the buffered records (buffered=True) in one call; nothing to do otherwise."""
        if self._buffer and self._fd is not None:
            records, self._buffer = b"".join([_record(stamp_s, frame) for stamp_s, frame in self._buffer]), []
            self._write(records)

    def _write(self, data: bytes) -> None:
        written = os.write(self._fd, data)
        while written < len(data):  # a regular file takes it all at once; be correct anyway
            written += os.write(self._fd, data[written:])
        if self.fsync:
            os.fsync(self._fd)

    @property
    def closed(self) -> bool:
        return self._fd is None

    def close(self) -> None:
        if self._fd is not None:
            self.flush()
            fd, self._fd = self._fd, None
            os.close(fd)

    def __enter__(self) -> TlogWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self):
        self.close()

    def __repr__(self) -> str:
        return f"TlogWriter({str(self.path)!r}, frames={self.frames_written})"


def read_tlog(path: str | Path, parser: FrameParser | None = None) -> list[tuple[float, Decoded]]:
    """Every decodable frame of a tlog with its time stamp (s). Reading stops at the first record that
    is not a MAVLink 2 frame (e.g. the incomplete last record of a killed writer)."""
    parser = FrameParser() if parser is None else parser
    try:
        data = Path(path).read_bytes()
    except OSError as err:
        raise UserError(f"{path}: cannot read tlog ({err.strerror})") from None
    out: list[tuple[float, Decoded]] = []
    pos = 0
    while pos + _TIMESTAMP.size + MIN_FRAME_LEN <= len(data):
        start = pos + _TIMESTAMP.size
        if data[start] != MAGIC_V2:
            break
        end = start + MIN_FRAME_LEN + data[start + 1]
        if data[start + 2] & IFLAG_SIGNED:
            end += SIGNATURE_BLOCK_LEN
        if end > len(data):
            break
        stamp_s = _TIMESTAMP.unpack_from(data, pos)[0] / 1e6
        out.extend((stamp_s, decoded) for decoded in parser.feed(data[start:end], final=True))
        pos = end
    return out
