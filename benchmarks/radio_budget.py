"""What each mode's traffic costs on one Crazyradio (issue 16, item 5): MAVLink and CRTP, per second of flight.

Prints, for the traffic cfstack actually sends (frame sizes from its own encoders, rates from its parameter
files): radio packets per second each way, the half-duplex transactions the dongle must run (the downlink
rides on acknowledgements: model.air_budget), the air time they take per second, and the transactions
against the dongle's USB cadence; then, per link and mode, the highest command rate (with the IMU telemetry
at the same rate on MAVLink, as moments mode needs) that still fits one radio.

The emulator's `crazyradio` profile flies this model (simulator.radio.EsbAir: one transaction per USB interval,
one packet each way per transaction); tests/simulator/test_crazyradio_air.py checks that the simulated air and
this budget agree on what fits.

Usage: python benchmarks/radio_budget.py [--usb-interval-ms MS] (default: the crazyradio profile's)
"""

from __future__ import annotations

import argparse
import dataclasses
import sys

import numpy as np

from groundstation.crtp_settings import load_crtp_link_settings
from groundstation.mission import load_mission_params
from link.crtp import appchannel
from link.keys import GROUND_STATION_SYSTEM_ID
from link.mavlink.codec import ActuatorLimits, Codec
from link.messages import (
    AttitudeTarget,
    BatteryStatus,
    ExternalPose,
    Heartbeat,
    ImuSample,
    RadioStatus,
    ThrustMoment,
    TimeSync,
)
from model.air_budget import AirBudget, air_budget
from model.radio import RadioProfile, load_radio_profile
from model.vehicle import load_mocap_room, load_vehicle
from simulator.firmware import load_firmware_params
from simulator.radio import DOWNLINK, UPLINK, EsbAir, RadioChannel

# CRTP payloads (data bytes after the header), from the packet layouts cflib and the firmware use
RPYT_BYTES = 14  # <fffH (commander.py send_setpoint)
EXTPOSE_BYTES = 29  # type + x y z qx qy qz qw floats (localization.py send_extpose)
LOG_HEADER_BYTES = 4  # block id + u24 timestamp (log.c)
IMU_LOG_BYTES = LOG_HEADER_BYTES + 6 * 4  # acc.x..z, gyro.x..z as floats
STATUS_LOG_BYTES = LOG_HEADER_BYTES + 2 + 4 + 1  # supervisor.info u16, pm.vbat float, pm.batteryLevel u8
COMMAND_RATES_HZ = (50.0, 100.0, 200.0, 250.0, 500.0, 1000.0)
SIMULATED_S = 10.0  # seconds of each traffic through the simulated air
PUSH_GRID_S = 0.001  # the streams are pushed on this grid (every rate here divides 1 kHz)


def mavlink_traffic(mode: str, command_hz: float, imu_hz: float):
    vehicle = load_vehicle("cf21")
    codec = Codec(system_id=GROUND_STATION_SYSTEM_ID, limits=ActuatorLimits.from_vehicle(vehicle))
    size = lambda message: len(codec.encode(message))  # noqa: E731 - a local shorthand
    mission, firmware = load_mission_params(), load_firmware_params()
    mocap_hz = load_mocap_room("vicon").rate_hz
    command = (ThrustMoment(1.0, 0.3, (1e-3, 1e-3, 1e-3)) if mode == "moments"
               else AttitudeTarget(1.0, 0.3, (1.0, 0.0, 0.0, 0.0)))
    uplink = [(command_hz, size(command)), (mocap_hz, size(ExternalPose(1.0, (1.0, 1.0, 1.0), (1.0, 0, 0, 0)))),
              (1.0 / mission.heartbeat_period_s, size(Heartbeat(armed=False, is_ground_station=True))),
              (1.0 / mission.timesync_period_s, size(TimeSync(0, 123456789)))]
    downlink = [(imu_hz, size(ImuSample(1.0, (0.1, 0.1, 9.8), (0.01, 0.01, 0.01)))),
                (firmware.heartbeat_rate_hz, size(Heartbeat(armed=True))),
                (firmware.battery_rate_hz, size(BatteryStatus(3.9, 80))),
                (1.0 / mission.timesync_period_s, size(TimeSync(123, 123456789))),
                (1.0, size(RadioStatus(200, 200, 90, 0, 0, 0, 0)))]
    return uplink, downlink


def crtp_traffic(mode: str, command_hz: float):
    settings, mission = load_crtp_link_settings(), load_mission_params()
    command_bytes = (len(appchannel.encode_thrust_moment(ThrustMoment(1.0, 0.3, (0.0, 0.0, 0.0))))
                     if mode == "moments" else RPYT_BYTES)
    sync_hz = 1.0 / mission.timesync_period_s
    uplink = [(command_hz, command_bytes), (load_mocap_room("vicon").rate_hz, EXTPOSE_BYTES),
              (sync_hz, len(appchannel.encode_time_sync(TimeSync(0, 1), reply=False)))]
    downlink = [(1000.0 / settings.imu_period_ms, IMU_LOG_BYTES),
                (1000.0 / settings.status_period_ms, STATUS_LOG_BYTES),
                (sync_hz, len(appchannel.encode_time_sync(TimeSync(1, 1), reply=True)))]
    return uplink, downlink


def run_traffic(profile: RadioProfile, uplink, downlink, seconds: float = SIMULATED_S,
                seed: int = 1) -> list[RadioChannel]:
    """The traffic through the emulator's radio of this profile (with "crazyradio": one half-duplex air,
    simulator.radio.EsbAir, shared by the two directions): each stream pushed at its rate from a common 1 ms grid.
    Returns the (uplink, downlink) channels."""
    air = EsbAir(profile.crazyradio, np.random.default_rng(seed)) if profile.model == "crazyradio" else None
    channels = [RadioChannel(profile, np.random.default_rng(seed + 1 + i), keep_ledger=False, air=air,
                             direction=direction) for i, direction in enumerate((UPLINK, DOWNLINK))]
    steps = round(seconds / PUSH_GRID_S)
    for channel, traffic in zip(channels, (uplink, downlink), strict=True):
        for step in range(steps):
            t = step * PUSH_GRID_S
            for hz, size in traffic:
                if step % max(1, round(1.0 / (hz * PUSH_GRID_S))) == 0:
                    channel.push(bytes(size), t)
            channel.pop_due(t)
    return channels


def simulate(profile: RadioProfile, uplink, downlink) -> str:
    """What each direction of run_traffic delivered and its 99th-percentile delay, as a line."""
    parts = [f"{name} {c.stats.delivered / c.stats.offered:5.1%} delivered, p99 {c.stats.latency_p99_s * 1e3:6.1f} ms"
             for name, c in zip(("up", "down"), run_traffic(profile, uplink, downlink), strict=True)]
    return "    simulated air: " + "; ".join(parts)


def row(label: str, budget: AirBudget) -> str:
    return (f"{label:<44} up {budget.uplink_packets_per_s:7.0f} pkt/s  down {budget.downlink_packets_per_s:7.0f} "
            f"pkt/s  transactions {budget.transactions_per_s:7.0f}/s  air {budget.air_s_per_s:5.2f} s/s  "
            f"USB {budget.usb_load:5.2f}  {'fits' if budget.fits else 'DOES NOT FIT'}")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    profile = load_radio_profile("crazyradio")
    link = profile.crazyradio
    p.add_argument("--usb-interval-ms", type=float, default=link.usb_interval_s * 1000.0,
                   help="one radio transaction per USB interval (default: the crazyradio profile's, whose source says "
                        "'USB works in 1 ms intervals'); 0 leaves USB out")
    args = p.parse_args()
    usb = 1000.0 / args.usb_interval_ms if args.usb_interval_ms > 0 else float("inf")
    imu_hz = load_vehicle("cf21").imu.rate_hz
    print(f"one Crazyradio at {link.air_rate_bps / 1e6:g} Mbit/s, per-attempt loss {link.packet_loss_probability:g}, "
          f"USB {usb:g} transactions/s\n")
    usb_profile = dataclasses.replace(profile, crazyradio=dataclasses.replace(
        link, usb_interval_s=args.usb_interval_ms / 1000.0))
    print(f"as cfstack flies today (each also through the emulator's crazyradio air for {SIMULATED_S:g} s):")
    for mode, hz in (("moments", 500.0), ("attitude", 100.0)):
        traffic = mavlink_traffic(mode, hz, imu_hz)
        print(row(f"MAVLink {mode}, command {hz:g} Hz, IMU {imu_hz:g} Hz", air_budget(link, *traffic, usb)))
        print(simulate(usb_profile, *traffic))
    for mode, hz in (("moments", 500.0), ("attitude", 100.0)):
        traffic = crtp_traffic(mode, hz)
        print(row(f"CRTP {mode}, command {hz:g} Hz, IMU 100 Hz", air_budget(link, *traffic, usb)))
        print(simulate(usb_profile, *traffic))
    print("\nthe highest command rate that fits (MAVLink: IMU telemetry at the command rate):")
    for name, traffic in (("MAVLink moments", lambda hz: mavlink_traffic("moments", hz, hz)),
                          ("MAVLink attitude", lambda hz: mavlink_traffic("attitude", hz, hz)),
                          ("CRTP moments", lambda hz: crtp_traffic("moments", hz)),
                          ("CRTP attitude", lambda hz: crtp_traffic("attitude", hz))):
        fitting = [hz for hz in COMMAND_RATES_HZ if air_budget(link, *traffic(hz), usb).fits]
        print(f"  {name:<18} {max(fitting):g} Hz" if fitting else f"  {name:<18} none of {COMMAND_RATES_HZ}")
        for hz in ([max(fitting)] if fitting else []) + [hz for hz in COMMAND_RATES_HZ if hz not in fitting][:1]:
            print(f"  at {hz:g} Hz" + simulate(usb_profile, *traffic(hz))[3:])
    return 0


if __name__ == "__main__":
    sys.exit(main())
