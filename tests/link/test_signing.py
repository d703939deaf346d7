"""link.mavlink.signing: key material, the MAVLink signature definition, interoperability with pymavlink, and
rejection of unsigned, forged and replayed frames."""

from __future__ import annotations

import argparse
import hashlib
import pickle
import struct
import time

import pytest
from pymavlink.dialects.v20 import common as mav

from link.mavlink.codec import Codec, FrameParser
from link.mavlink.signing import (
    ENV_VAR,
    MAVLINK_EPOCH_UNIX_S,
    Signing,
    add_signing_arguments,
    key_from_material,
    load_key_file,
    signing_from_args,
    signing_from_options,
)
from link.messages import Heartbeat, RadioStatus, TimeSync
from model.errors import UserError

KEY = bytes(range(100, 132))
OTHER_KEY = bytes(32)
NOW = MAVLINK_EPOCH_UNIX_S + 300_000_000.0  # 2024-07-05, a fixed wall clock for the tests


def fixed_clock(t: float = NOW):
    return lambda: t


FIXED_CLOCK = fixed_clock()


def pair(key_tx=KEY, key_rx=KEY, tx_clock=FIXED_CLOCK, rx_clock=FIXED_CLOCK):
    codec = Codec(5, 1, signing=Signing(key_tx, 2, clock=tx_clock) if key_tx else None)
    parser = FrameParser(signing=Signing(key_rx, 0, clock=rx_clock) if key_rx else None)
    return codec, parser


# -- key material ----------------------------------------------------------------------------------


def test_key_file_forms(tmp_path):
    raw = tmp_path / "raw.key"
    raw.write_bytes(KEY)
    hexed = tmp_path / "hex.key"
    hexed.write_text(KEY.hex().upper() + "\n")
    phrase = tmp_path / "phrase.key"
    phrase.write_text("  correct horse battery staple\n")
    assert load_key_file(raw) == KEY
    assert load_key_file(hexed) == KEY
    assert load_key_file(phrase) == hashlib.sha256(b"correct horse battery staple").digest()


def test_bad_key_files_give_one_line_errors_without_the_key(tmp_path):
    empty = tmp_path / "empty.key"
    empty.write_text("\n\n")
    with pytest.raises(UserError, match="empty") as err:
        load_key_file(empty)
    assert str(empty) in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(UserError, match="cannot read") as err:
        load_key_file(tmp_path / "missing.key")
    assert "missing.key" in str(err.value)


def test_environment_variable_and_precedence(tmp_path):
    env = {ENV_VAR: KEY.hex()}
    signing = signing_from_options(None, env=env)
    assert signing is not None and signing._key == KEY
    phrase = signing_from_options(None, env={ENV_VAR: "open sesame"})
    assert phrase._key == hashlib.sha256(b"open sesame").digest()
    key_file = tmp_path / "k"
    key_file.write_bytes(OTHER_KEY)
    assert signing_from_options(key_file, env=env)._key == OTHER_KEY  # the file wins
    assert signing_from_options(None, env={}) is None
    assert signing_from_options(None, env={ENV_VAR: "  "}) is None


def test_command_line_takes_a_file_never_the_key(tmp_path, monkeypatch):
    parser = argparse.ArgumentParser()
    add_signing_arguments(parser)
    assert [a.dest for a in parser._actions if a.dest.startswith("signing")] == ["signing_key_file"]
    key_file = tmp_path / "k"
    key_file.write_bytes(KEY)
    monkeypatch.delenv(ENV_VAR, raising=False)
    assert signing_from_args(parser.parse_args(["--signing-key-file", str(key_file)]))._key == KEY
    assert signing_from_args(parser.parse_args([])) is None


def test_key_is_never_shown():
    signing = Signing(KEY, 3)
    for text in (repr(signing), str(signing), f"{signing}", repr(Codec(1, signing=signing))):
        assert KEY.hex() not in text and str(KEY) not in text and "hidden" in text
    with pytest.raises(TypeError):
        pickle.dumps(signing)
    with pytest.raises(UserError):
        Signing(b"short")
    assert key_from_material(b"x" * 64, "src") == hashlib.sha256(b"x" * 64).digest()  # 64 chars, not hex


# -- the signature on the wire ---------------------------------------------------------------------


def test_signature_follows_the_mavlink_definition():
    codec, _ = pair()
    frame = codec.encode(TimeSync(0, 1))
    assert frame[2] & 0x01  # incompat flag "signed"
    body = frame[:-13]
    link_id = frame[-13]
    timestamp = int.from_bytes(frame[-12:-6], "little")
    assert link_id == 2
    assert timestamp == round((NOW - MAVLINK_EPOCH_UNIX_S) * 100_000)  # 10 us units since 2015
    assert frame[-6:] == hashlib.sha256(KEY + body + frame[-13:-6]).digest()[:6]


def test_timestamps_strictly_increase_even_when_the_clock_stands_still():
    signing = Signing(KEY, 0, clock=fixed_clock())
    stamps = [signing.next_timestamp() for _ in range(100)]
    assert all(b > a for a, b in zip(stamps, stamps[1:], strict=False))


def test_pymavlink_accepts_our_signed_frames_and_we_accept_its():
    codec, parser = pair(tx_clock=time.time, rx_clock=time.time)
    theirs = mav.MAVLink(None, 9, 1)
    theirs.signing.secret_key = KEY
    theirs.signing.sign_outgoing = True
    theirs.signing.link_id = 4
    theirs.signing.timestamp = Signing(KEY).clock_units()
    decoded = theirs.decode(bytearray(codec.encode(Heartbeat(True))))
    assert decoded.get_signed() and decoded.get_type() == "HEARTBEAT"
    frame = theirs.timesync_encode(0, 77).pack(theirs)
    (ours,) = parser.feed(frame)
    assert ours.signed and ours.link_id == 4 and ours.message == TimeSync(0, 77)


def test_signed_frames_pass_a_receiver_without_signing_unverified():
    codec, _ = pair()
    (d,) = FrameParser().feed(codec.encode(TimeSync(0, 1)))
    assert d.message == TimeSync(0, 1) and not d.signed


# -- rejections ------------------------------------------------------------------------------------


def test_good_signed_frames_are_delivered():
    codec, parser = pair()
    out = [d for i in range(5) for d in parser.feed(codec.encode(TimeSync(0, i)))]
    assert [d.message.origin_ns for d in out] == list(range(5)) and all(d.signed for d in out)
    assert parser.counters.signature_failures == 0


def test_unsigned_frames_are_rejected():
    codec, parser = pair(key_tx=None)
    assert parser.feed(codec.encode(TimeSync(0, 1))) == []
    assert parser.counters.unsigned_rejected == 1 and parser.counters.signature_failures == 1


def test_wrong_key_is_rejected():
    codec, parser = pair(key_tx=OTHER_KEY)
    assert parser.feed(codec.encode(TimeSync(0, 1))) == []
    assert parser.counters.bad_signatures == 1


def test_altered_frame_with_a_fixed_up_crc_is_rejected():
    codec, parser = pair()
    frame = bytearray(codec.encode(TimeSync(0, 1)))
    frame[10] ^= 0x01  # change the payload, then repair the CRC as an attacker can
    end = len(frame) - 13
    crc = mav.x25crc(bytes(frame[1:end - 2]) + bytes([mav.MAVLink_timesync_message.crc_extra])).crc
    frame[end - 2:end] = struct.pack("<H", crc)
    assert parser.feed(bytes(frame)) == []
    assert parser.counters.bad_signatures == 1 and parser.counters.crc_failures == 0


def test_replayed_frame_is_rejected():
    codec, parser = pair()
    frame = codec.encode(TimeSync(0, 1))
    assert len(parser.feed(frame)) == 1
    assert parser.feed(frame) == []
    assert parser.counters.replays_rejected == 1
    older, newer = codec.encode(TimeSync(0, 2)), codec.encode(TimeSync(0, 3))
    assert len(parser.feed(newer)) == 1 and parser.feed(older) == []  # not newer than the last seen
    assert parser.counters.replays_rejected == 2


def test_recording_replayed_after_a_restart_is_rejected():
    codec, _ = pair(tx_clock=fixed_clock(NOW - 120.0))  # recorded two minutes ago
    _, fresh_receiver = pair()
    assert fresh_receiver.feed(codec.encode(TimeSync(0, 1))) == []
    assert fresh_receiver.counters.replays_rejected == 1


def test_forged_future_timestamp_does_not_block_the_genuine_stream():
    codec, parser = pair()
    forger = Codec(5, 1, signing=Signing(OTHER_KEY, 2, clock=fixed_clock(NOW + 1e6)))
    assert parser.feed(forger.encode(TimeSync(0, 666))) == []
    assert len(parser.feed(codec.encode(TimeSync(0, 1)))) == 1  # pymavlink's check would refuse this


def test_streams_are_kept_apart_by_system_component_and_link():
    codec_a = Codec(5, 1, signing=Signing(KEY, 2, clock=fixed_clock(NOW + 10.0)))
    codec_b = Codec(6, 1, signing=Signing(KEY, 2, clock=fixed_clock(NOW)))
    parser = FrameParser(signing=Signing(KEY, 0, clock=fixed_clock()))
    assert len(parser.feed(codec_a.encode(TimeSync(0, 1)))) == 1
    assert len(parser.feed(codec_b.encode(TimeSync(0, 2)))) == 1  # older stamp, but another stream


def test_unsigned_exceptions_are_explicit():
    signing = Signing(KEY, 0, clock=fixed_clock(), allow_unsigned_msgids={mav.MAVLINK_MSG_ID_RADIO_STATUS})
    parser = FrameParser(signing=signing)
    radio = Codec(51).encode(RadioStatus(1, 2, 3, 4, 5, 6, 7))
    (d,) = parser.feed(radio)
    assert not d.signed
    assert parser.feed(Codec(51).encode(TimeSync(0, 1))) == []
