"""Zenoh key expressions of cfstack, one place for all of them.

Takes in: a key prefix (`--id PREFIX`, default "cfstack") and a vehicle id (MAVLink system id, 1..250).
Gives out: the key of each channel. Directions and rates are documented in README.md.
"""

from __future__ import annotations

from dataclasses import dataclass

DEFAULT_PREFIX = "cfstack"
GROUND_STATION_SYSTEM_ID = 255
MAX_VEHICLE_ID = 250  # vehicles are MAVLink system ids 1..250; 251..255 are ground-side ids
MOCAP_SYSTEM_ID = 254


@dataclass(frozen=True)
class VehicleKeys:
    prefix: str
    vehicle_id: int

    @property
    def uplink(self) -> str:  # ground station -> vehicle, through the (simulated) radio
        return f"{self.prefix}/vehicle/{self.vehicle_id}/uplink"

    @property
    def downlink(self) -> str:  # vehicle -> ground station, through the (simulated) radio
        return f"{self.prefix}/vehicle/{self.vehicle_id}/downlink"

    @property
    def crtp_uplink(self) -> str:  # ground station -> vehicle, CRTP packets (one per sample), through the radio
        return f"{self.prefix}/vehicle/{self.vehicle_id}/crtp/uplink"

    @property
    def crtp_downlink(self) -> str:  # vehicle -> ground station, CRTP packets (one per sample), through the radio
        return f"{self.prefix}/vehicle/{self.vehicle_id}/crtp/downlink"

    @property
    def mocap(self) -> str:  # mocap system -> ground network (never over the radio)
        return f"{self.prefix}/mocap/{self.vehicle_id}"

    @property
    def truth(self) -> str:  # SIMULATION ONLY: ground truth for logs and grading
        return f"{self.prefix}/sim/truth/{self.vehicle_id}"

    @property
    def clock(self) -> str:  # lockstep: emulator -> ground station, simulation clock ticks
        return f"{self.prefix}/sim/clock/{self.vehicle_id}"

    @property
    def clock_ack(self) -> str:  # lockstep: ground station -> emulator, "tick done"
        return f"{self.prefix}/sim/clock_ack/{self.vehicle_id}"
