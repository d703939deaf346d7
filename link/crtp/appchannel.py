"""cfstack's packets on the Crazyflie's app channel: what stock firmware has no setpoint for.

Takes in: cfstack messages (ThrustMoment, TimeSync) to encode, or an app-channel payload to decode.
Gives out: the payload bytes (at most 30: one CRTP packet on platform port 13, channel 2, cflib's
`cf.appchannel.send_packet`), or the decoded message; None for a payload that is not one of ours, a
Malformed record for one of ours cut short.

The app channel (firmware app_channel.c, cflib appchannel.py) carries raw bytes between a client and an
app compiled into the firmware (an out-of-tree app, `APP=1`); the stock firmware drops them. On the
emulated Crazyflie these packets are understood as if that app were built in. What a real Crazyflie
needs for them (README, "The ground station's Crazyflie link"): an app that reads the channel with
appchannelReceiveDataPacket, and for THRUST_MOMENT feeds the power distribution a force-torque control
(control_t mode controlModeForceTorque: thrustSi in N, torqueX/Y/Z in N m, as
power_distribution_quadrotor.c takes it from the Lee controller) while the setpoints are fresh; for
TIME_SYNC answers with usecTimestamp().

Packets (little-endian; the first byte is the type):
- THRUST_MOMENT (1), ground -> vehicle, `<BIffff` 21 bytes: the command's time (us, the ground station's
  clock, mod 2^32), collective thrust (N), moments about the body x, y, z axes (FLU, N m).
- TIME_SYNC (2), ground -> vehicle `<Bq` 9 bytes: the request's time (ns, the ground station's clock);
  vehicle -> ground `<Bqq` 17 bytes: that time echoed, the vehicle's clock when it answered (ns).
"""

from __future__ import annotations

import struct

from link.crtp.setpoints import Malformed
from link.messages import ThrustMoment, TimeSync

APP_CHANNEL = 2  # platform port 13, channel 2 (firmware platformservice.c, cflib appchannel.py)
THRUST_MOMENT, TIME_SYNC = 1, 2
_THRUST_MOMENT = struct.Struct("<BIffff")
_TIME_SYNC_REQUEST = struct.Struct("<Bq")
_TIME_SYNC_REPLY = struct.Struct("<Bqq")
US_WRAP = 1 << 32


def encode_thrust_moment(message: ThrustMoment) -> bytes:
    time_us = round(message.time_s * 1e6) % US_WRAP
    return _THRUST_MOMENT.pack(THRUST_MOMENT, time_us, message.thrust_n, *message.moment_flu_nm)


def encode_time_sync(message: TimeSync, reply: bool) -> bytes:
    """A request (the ground station's) or a reply (the vehicle's, with its clock in remote_ns)."""
    if reply:
        return _TIME_SYNC_REPLY.pack(TIME_SYNC, message.origin_ns, message.remote_ns)
    return _TIME_SYNC_REQUEST.pack(TIME_SYNC, message.origin_ns)


def decode(payload: bytes, from_vehicle: bool):
    """The message of an app-channel payload: ThrustMoment (time_s mod 2^32 us) or TimeSync (a request
    has remote_ns 0); Malformed for one of ours of the wrong length; None for another app's."""
    if not payload:
        return None
    kind = payload[0]
    if kind == THRUST_MOMENT and not from_vehicle:
        if len(payload) != _THRUST_MOMENT.size:
            return Malformed(f"app-channel thrust-moment: {len(payload)} bytes, expected {_THRUST_MOMENT.size}")
        _, time_us, thrust, mx, my, mz = _THRUST_MOMENT.unpack(payload)
        return ThrustMoment(time_us * 1e-6, thrust, (mx, my, mz))
    if kind == TIME_SYNC:
        layout = _TIME_SYNC_REPLY if from_vehicle else _TIME_SYNC_REQUEST
        if len(payload) != layout.size:
            return Malformed(f"app-channel time-sync: {len(payload)} bytes, expected {layout.size}")
        values = layout.unpack(payload)
        return TimeSync(remote_ns=values[2] if from_vehicle else 0, origin_ns=values[1])
    return None
