"""`serial:DEVICE:BAUD` - a byte stream over a serial port (a radio modem, a USB UART, a pty).

Takes in: DEVICE (a path such as /dev/ttyUSB0, or a name such as COM3) and BAUD (bits per second, a
positive integer), e.g. `serial:/dev/ttyUSB0:57600`. Options: `write_timeout_s` (longest a send may
wait for room in the driver's buffer, default DEFAULT_WRITE_TIMEOUT_S).
Gives out: a point-to-point stream transport (channel names are ignored). send() writes the frame's
bytes; receive() returns raw byte chunks as they arrived, cut anywhere: link.mavlink.codec's stream parser
reassembles frames and skips line noise.
Reads are non-blocking (pyserial timeout=0) after select() waits at most `timeout_s`.
"""

from __future__ import annotations

import select
import time

import serial

from link.transports.base import Transport
from model.errors import UserError

# Long enough for a full 4 kB driver buffer to drain at 57600 baud (~0.7 s), short enough that a
# stalled device cannot hang the caller.
DEFAULT_WRITE_TIMEOUT_S = 1.0
# Bytes taken per receive() call: a pty or a USB UART hands over at most a few kB at a time.
READ_CHUNK_BYTES = 65536


def parse_device_baud(address: str) -> tuple[str, int]:
    """'DEVICE:BAUD' -> (device, baud); a one-line UserError naming the address."""
    device, sep, baud_text = address.rpartition(":")
    if not sep or not device or not baud_text:
        raise UserError(f"'serial:{address}' is not serial:DEVICE:BAUD (e.g. serial:/dev/ttyUSB0:57600)")
    try:
        baud = int(baud_text)
    except ValueError:
        raise UserError(f"'serial:{address}': baud '{baud_text}' is not a whole number "
                        "(e.g. serial:/dev/ttyUSB0:57600)") from None
    if baud <= 0:
        raise UserError(f"'serial:{address}': baud must be positive, got {baud}")
    return device, baud


class SerialTransport(Transport):
    scheme = "serial"

    def __init__(self, address: str, tx: str | None = None, rx: str | None = None, **options):
        super().__init__(address, tx=tx, rx=rx, **options)
        unknown = set(options) - {"write_timeout_s"}
        if unknown:
            raise UserError(f"serial:{address}: unknown option(s) {', '.join(sorted(unknown))} "
                            "(known: write_timeout_s)")
        self.device, self.baud = parse_device_baud(address)
        self.write_timeout_s = float(options.get("write_timeout_s", DEFAULT_WRITE_TIMEOUT_S))
        self.device_lost = False  # the device vanished (USB unplugged, pty closed); receive waits out
        self._port: serial.Serial | None = None

    def open(self) -> None:
        if self.is_open:
            return
        try:
            self._port = serial.Serial(self.device, self.baud, timeout=0, write_timeout=self.write_timeout_s)
        except (serial.SerialException, ValueError, OSError) as err:
            reason = _first_line(err)
            raise UserError(f"serial:{self.address}: cannot open {self.device} ({reason})") from None
        self.device_lost = False
        self.is_open = True

    def close(self) -> None:
        if not self.is_open:
            return
        self.is_open = False
        try:
            self._port.close()
        except (serial.SerialException, OSError):
            pass  # the device is already gone; nothing left to release
        self._port = None

    def send(self, frame: bytes) -> bool:
        if not self.is_open or self.device_lost:
            return self.stats.record_send(len(frame), False)
        try:
            self._port.write(frame)
        except (serial.SerialException, OSError):  # write timeout (possibly partial) or device gone
            return self.stats.record_send(len(frame), False)
        return self.stats.record_send(len(frame), True)

    def receive(self, timeout_s: float = 0.0) -> list[bytes]:
        if not self.is_open:
            return []
        deadline = time.monotonic() + max(0.0, timeout_s)
        if not self.device_lost:
            try:
                readable, _, _ = select.select([self._port.fileno()], [], [], max(0.0, timeout_s))
                chunk = self._port.read(READ_CHUNK_BYTES) if readable else b""
            except (serial.SerialException, OSError, ValueError):
                self.device_lost = True
        if self.device_lost:
            # A vanished device is always "readable"; wait out the timeout so callers do not spin.
            time.sleep(max(0.0, deadline - time.monotonic()))
            return []
        if not chunk:
            return []
        self.stats.chunks_received += 1
        self.stats.bytes_received += len(chunk)
        return [chunk]


def _first_line(err: Exception) -> str:
    cause = err.__context__
    if isinstance(cause, OSError) and cause.strerror:  # pyserial wraps the OSError saying what went wrong
        return cause.strerror
    text = str(err).strip()
    return text.splitlines()[0] if text else type(err).__name__
