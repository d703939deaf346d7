"""CRTP packets: one header byte (port, channel) and at most 30 bytes of payload.

Takes in: a datagram (bytes) as a CRTP link carries it (cflib's udp:// driver: one packet per datagram).
Gives out: CrtpPacket(port, channel, data), or None for what is no packet (empty, or a payload longer
than CRTP_MAX_DATA); `encode` gives the datagram back.

Header (cflib crtpstack.py, firmware crtp.h): port << 4 | 0b1100 | channel. The two middle bits are the
legacy bootloader bits: cflib sets them when it sends and ignores them when it receives, so a decoder
ignores them too. A null packet (port 15, channel 3, e.g. 0xFF) carries nothing; cflib's UDP scan sends
one to every port 19850-19859 and takes any answer as a Crazyflie there.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

DEFAULT_CRTP_PORT = 19850  # CrazySim's: vehicle N (from 1) at 19850 + N - 1; cflib's UDP scan covers 19850-19859
CRTP_HOST = "127.0.0.1"
CRTP_MAX_DATA = 30  # firmware crtp.h CRTP_MAX_DATA_SIZE; cflib CRTPPacket.MAX_DATA_SIZE
LEGACY_BITS = 0x0C
NULL_MASK = 0xF3  # (header & NULL_MASK) == NULL_MASK: a null packet (firmware CRTP_IS_NULL_PACKET)


class Port(IntEnum):
    """CRTP ports (cflib CRTPPort, firmware crtp.h)."""

    CONSOLE = 0
    PARAM = 2
    COMMANDER = 3
    MEM = 4
    LOG = 5
    LOCALIZATION = 6
    GENERIC_SETPOINT = 7
    HIGH_LEVEL = 8
    SUPERVISOR = 9
    PLATFORM = 13
    LINK = 15


@dataclass(frozen=True)
class CrtpPacket:
    port: int
    channel: int
    data: bytes = b""


def is_null(datagram: bytes) -> bool:
    """A null packet (header port 15, channel 3, legacy bits either way)."""
    return bool(datagram) and (datagram[0] & NULL_MASK) == NULL_MASK


def decode(datagram: bytes) -> CrtpPacket | None:
    """The packet in a datagram; None for an empty or oversized one."""
    if not datagram or len(datagram) > 1 + CRTP_MAX_DATA:
        return None
    header = datagram[0]
    return CrtpPacket(header >> 4, header & 0x03, bytes(datagram[1:]))


def encode(packet: CrtpPacket) -> bytes:
    """The datagram of a packet (legacy bits set, as cflib and the firmware's CRTP_HEADER do)."""
    if len(packet.data) > CRTP_MAX_DATA:
        raise ValueError(f"CRTP payload of {len(packet.data)} bytes exceeds {CRTP_MAX_DATA}")
    if not (0 <= packet.port <= 15 and 0 <= packet.channel <= 3):
        raise ValueError(f"CRTP port {packet.port} / channel {packet.channel} out of range")
    return bytes((packet.port << 4 | LEGACY_BITS | packet.channel,)) + packet.data
