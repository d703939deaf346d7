"""MAVLink 2 message signing: the secret key, outgoing signatures, and checks of incoming ones.

Takes in: a 32-byte secret key (from `--signing-key-file PATH` or the environment variable
CFSTACK_SIGNING_KEY, never from the command line), a link id (0..255) and a wall clock.
Gives out: `Signing`, which the codec uses to append the 13-byte signature block to outgoing frames
and the frame parser uses to accept or reject incoming frames (`SignatureCheck`).

Wire format (mavlink.io "Message signing"): a signed frame has incompat flag 0x01 and ends with
    link_id (1 byte) | timestamp (6 bytes, little-endian) | signature (6 bytes)
where timestamp counts 10 us units since 2015-01-01 00:00:00 UTC and
    signature = first 6 bytes of SHA-256(secret_key + header + payload + crc + link_id + timestamp),
the header starting at the 0xFD magic byte. It is computed here with hashlib, not with pymavlink's
signing, because pymavlink records a stream's timestamp before checking the signature (so one forged
frame with a far-future timestamp makes every later genuine frame look like a replay).

Acceptance, with signing on: a frame is delivered only if it is signed, its signature matches, and its
timestamp is newer than the last accepted one of its stream (source system, source component, link id);
a stream's first frame must not be more than `new_stream_window_s` older than our clock (the spec's
one-minute rule, so frames recorded earlier cannot be replayed after a restart). Unsigned frames are
rejected unless their message id is in `allow_unsigned_msgids` (empty by default).

Key material (`key_from_material`): a file of exactly 32 bytes is the raw key; 64 hexadecimal characters
(surrounding whitespace ignored) are the hex-encoded key; anything else is a passphrase (surrounding
whitespace stripped, UTF-8) whose SHA-256 digest is the key. The environment variable is read the same
way except that it cannot hold a raw key. The key never appears in repr, str or error messages.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import struct
import time
from collections.abc import Callable, Iterable, Mapping
from enum import Enum
from pathlib import Path

from model.errors import UserError

ENV_VAR = "CFSTACK_SIGNING_KEY"
KEY_LEN = 32
SIGNATURE_BLOCK_LEN = 13  # link id (1) + timestamp (6) + signature (6)
MAVLINK_EPOCH_UNIX_S = 1_420_070_400  # 2015-01-01T00:00:00Z, the origin of signing timestamps
TIMESTAMP_UNITS_PER_S = 100_000  # signing timestamps count 10 us units
NEW_STREAM_WINDOW_S = 60.0  # mavlink.io: a new stream may lag our clock by at most one minute
_TIMESTAMP_MAX = (1 << 48) - 1
_STAMP = struct.Struct("<Q")  # the 6-byte timestamp is the low bytes of this


class SignatureCheck(Enum):
    OK = "ok"
    UNSIGNED = "unsigned"  # no signature block while signing is on
    BAD = "bad"  # signature does not match (wrong key or altered frame)
    REPLAY = "replay"  # timestamp not newer than the stream's last, or a stale new stream


class Signing:
    """Signs outgoing frames and checks incoming ones for one link (one link id).

    One instance may be shared by the codec (sending) and the parser (receiving) of an endpoint, as
    MAVLink intends: the local timestamp then also advances past every accepted incoming timestamp.
    """

    def __init__(
        self,
        key: bytes,
        link_id: int = 0,
        *,
        clock: Callable[[], float] = time.time,
        allow_unsigned_msgids: Iterable[int] = (),
        new_stream_window_s: float = NEW_STREAM_WINDOW_S,
    ):
        if not isinstance(key, bytes | bytearray) or len(key) != KEY_LEN:
            raise UserError(f"signing key must be {KEY_LEN} bytes")
        if not 0 <= link_id <= 255:
            raise UserError(f"signing link id {link_id} out of range 0..255")
        self._key = bytes(key)
        self.link_id = link_id
        self._link_byte = bytes([link_id])
        self._clock = clock
        self.allow_unsigned_msgids = frozenset(allow_unsigned_msgids)
        self._window_units = int(new_stream_window_s * TIMESTAMP_UNITS_PER_S)
        self._timestamp = 0  # last timestamp sent or accepted (10 us units since 2015)
        self._streams: dict[tuple[int, int, int], int] = {}

    def __repr__(self) -> str:
        return f"Signing(link_id={self.link_id}, key=<hidden>, streams={len(self._streams)})"

    __str__ = __repr__

    def __reduce__(self):
        raise TypeError("Signing holds a secret key and cannot be pickled")

    # -- sending ---------------------------------------------------------------------------------

    def clock_units(self) -> int:
        """Our clock in signing units: 10 us since 2015-01-01 UTC."""
        return int((self._clock() - MAVLINK_EPOCH_UNIX_S) * TIMESTAMP_UNITS_PER_S)

    def next_timestamp(self) -> int:
        """A timestamp strictly greater than every one this link sent or accepted."""
        stamp = max(self.clock_units(), self._timestamp + 1)
        self._timestamp = stamp
        return stamp

    def signature_block(self, unsigned_frame: bytes | bytearray) -> bytes:
        """The 13 bytes to append to a frame (header with flag 0x01 set, payload, crc)."""
        tail = self._link_byte + _STAMP.pack(self.next_timestamp())[:6]
        digest = hashlib.sha256(self._key + unsigned_frame + tail).digest()
        return tail + digest[:6]

    # -- receiving -------------------------------------------------------------------------------

    def check(self, frame: bytes | bytearray, system_id: int, component_id: int) -> SignatureCheck:
        """Check a whole signed frame (ending with its 13-byte block); remember its timestamp if OK."""
        body_end = len(frame) - 6
        expected = hashlib.sha256(self._key + frame[:body_end]).digest()[:6]
        if expected != frame[body_end:]:
            return SignatureCheck.BAD
        link_id = frame[-13]
        stamp = int.from_bytes(frame[-12:-6], "little")
        stream = (system_id, component_id, link_id)
        last = self._streams.get(stream)
        if last is None:
            if stamp + self._window_units < max(self._timestamp, self.clock_units()):
                return SignatureCheck.REPLAY
        elif stamp <= last:
            return SignatureCheck.REPLAY
        self._streams[stream] = stamp
        if stamp > self._timestamp:
            self._timestamp = min(stamp, _TIMESTAMP_MAX)
        return SignatureCheck.OK


# -- key material ------------------------------------------------------------------------------


def key_from_material(material: bytes, source: str) -> bytes:
    """The 32-byte key a file's (or variable's) content denotes; see the module docstring."""
    if len(material) == KEY_LEN:
        return bytes(material)
    text = material.strip()
    if len(text) == 2 * KEY_LEN:
        try:
            return bytes.fromhex(text.decode("ascii"))
        except (UnicodeDecodeError, ValueError):
            pass  # 64 characters but not hex: a passphrase
    if not text:
        raise UserError(f"{source}: signing key is empty")
    return hashlib.sha256(text).digest()


def load_key_file(path: str | Path) -> bytes:
    path = Path(path)
    try:
        material = path.read_bytes()
    except OSError as err:
        raise UserError(f"{path}: cannot read signing key file ({err.strerror})") from None
    return key_from_material(material, str(path))


def key_from_environment(env: Mapping[str, str] | None = None) -> bytes | None:
    value = (os.environ if env is None else env).get(ENV_VAR, "")
    if not value.strip():
        return None
    return key_from_material(value.encode("utf-8"), f"environment variable {ENV_VAR}")


def signing_from_options(
    key_file: str | Path | None,
    link_id: int = 0,
    *,
    env: Mapping[str, str] | None = None,
    clock: Callable[[], float] = time.time,
) -> Signing | None:
    """Signing from `--signing-key-file` if given, else from CFSTACK_SIGNING_KEY, else None (off)."""
    key = load_key_file(key_file) if key_file is not None else key_from_environment(env)
    return None if key is None else Signing(key, link_id, clock=clock)


def signing_from_args(args: argparse.Namespace, link_id: int = 0) -> Signing | None:
    """Signing from the options `add_signing_arguments` added (then the environment), or None."""
    return signing_from_options(getattr(args, "signing_key_file", None), link_id)


def add_signing_arguments(parser: argparse.ArgumentParser) -> None:
    """Add `--signing-key-file PATH` (the only way to give a key on a command line is by file)."""
    parser.add_argument(
        "--signing-key-file",
        metavar="PATH",
        default=None,
        help=f"sign MAVLink frames and reject unsigned/forged/replayed ones; PATH holds 32 raw bytes, "
        f"64 hex characters, or a passphrase (hashed with SHA-256). Default: ${ENV_VAR} if set, "
        f"else no signing",
    )
