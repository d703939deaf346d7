"""The lockstep simulation clock: a small protocol beside MAVLink, never subject to radio loss.

Takes in: the emulator's tick (tick index, simulation time, how many samples it has published on each
of a vehicle's keys so far; a sample holds one or more whole MAVLink frames, or one CRTP packet) and a
ground station's acknowledgement (tick index, how many uplink frames or CRTP packets it has sent so far,
when it next wants to be woken).
Gives out: fixed-size little-endian records for the clock keys (link.keys), and their decoding.

Why counts: zenoh keeps order per key, not across keys. A ground station that has seen tick k waits
until it holds `downlink_published` downlink samples (`crtp_published` CRTP samples, if it speaks
CRTP), so it never computes on a partial tick; the emulator likewise waits for `uplink_sent` uplink
frames before stepping on. That makes lockstep runs
byte-identical whatever the scheduling.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

_TICK = struct.Struct("<4sqqqqqq")
_ACK = struct.Struct("<4sqqqqB")
_TICK_MAGIC = b"CLK2"  # CLK1 had no crtp_published
_ACK_MAGIC = b"ACK2"  # ACK1 had no period_ns
NS_PER_S = 1_000_000_000


@dataclass(frozen=True)
class ClockTick:
    tick: int
    time_ns: int
    downlink_published: int
    mocap_published: int
    truth_published: int
    crtp_published: int = 0  # CRTP packets on the vehicle's crtp/downlink key (link.keys)

    @property
    def time_s(self) -> float:
        return self.time_ns / NS_PER_S

    def pack(self) -> bytes:
        return _TICK.pack(_TICK_MAGIC, self.tick, self.time_ns, self.downlink_published,
                          self.mocap_published, self.truth_published, self.crtp_published)


@dataclass(frozen=True)
class ClockAck:
    """A ground station's reply to tick `tick` (-1 = join). `leaving` = it takes no further part.
    `crtp`: its uplink_sent counts the CRTP packets it sent on the vehicle's crtp/uplink key (it speaks
    CRTP on its radio), not MAVLink frames.

    `period_ns` > 0 is a standing order: after every tick at time t this ground station wants the next
    at t + period_ns; its next_wakeup_ns must say the same, and the emulator goes by the period. It lets
    the emulator decide a tick's time before the previous tick's acks are in, and so publish it as early
    as the lookahead allows (simulator.emulator). 0: no promise, each ack's next_wakeup_ns decides."""

    tick: int
    uplink_sent: int
    next_wakeup_ns: int
    leaving: bool = False
    period_ns: int = 0
    crtp: bool = False

    def pack(self) -> bytes:
        return _ACK.pack(_ACK_MAGIC, self.tick, self.uplink_sent, self.next_wakeup_ns, self.period_ns,
                         int(self.leaving) | int(self.crtp) << 1)


def unpack_tick(data: bytes) -> ClockTick | None:
    if len(data) != _TICK.size or data[:4] != _TICK_MAGIC:
        return None
    _, *fields = _TICK.unpack(data)
    return ClockTick(*fields)


def unpack_ack(data: bytes) -> ClockAck | None:
    if len(data) != _ACK.size or data[:4] != _ACK_MAGIC:
        return None
    _, tick, sent, wake, period, flags = _ACK.unpack(data)
    return ClockAck(tick, sent, wake, bool(flags & 1), max(0, period), bool(flags & 2))
