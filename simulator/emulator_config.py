"""What an emulator runs with: the EmulatorConfig and its checks.

Takes in: the vehicle, mocap room and radio descriptions (model/), a world, and the run's settings (fleet
size, seed, clock, physics rate, connection, start, fault windows, signing).
Gives out: a checked EmulatorConfig (a one-line UserError for settings no emulator can run with).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

from link.keys import MAX_VEHICLE_ID
from link.transports.table import check_radio_link
from model.errors import UserError
from model.radio import RadioProfile
from model.vehicle import MocapRoom, Vehicle
from model.world import World
from simulator.faults import Outage

MAX_VEHICLES = MAX_VEHICLE_ID  # one MAVLink system id each


@dataclass
class EmulatorConfig:
    vehicle: Vehicle
    mocap_room: MocapRoom
    radio: RadioProfile  # the MAVLink radio's (both directions)
    world: World | None
    vehicles: int = 1
    seed: int = 0
    clock: str = "lockstep"  # or "realtime"
    physics_rate_hz: float = 1000.0
    prefix: str = "cfstack"
    connection: str = "zenoh"
    zenoh_options: dict = field(default_factory=dict)
    # the radio link (each vehicle's uplink and downlink, after its simulated radio) on its own connection
    # string, e.g. udpin:127.0.0.1:14560 (vehicle N on PORT+N-1) or serial:/dev/pts/3:57600; None: on
    # `connection` with the vehicle's keys. Mocap, truth and the lockstep clock stay on `connection`.
    radio_link: str | None = None
    start_positions_enu_m: list[tuple[float, float, float]] | None = None
    airborne: bool = False
    # the onboard side, "ideal" or "crazyflie" (simulator.vehicle_sim.make_firmware; the CLI default is crazyflie)
    firmware: str = "ideal"
    ideal_parts: tuple[str, ...] = ()  # ablation: faithful-firmware parts made ideal (estimator, battery)
    variation: object | None = None  # simulator.variation.VariationProfile: each vehicle's own draw; None: nominal
    signing: object | None = None
    duration_s: float | None = None  # stop after this much simulation time (None: until stopped)
    lookahead: bool = True  # lockstep: run physics ahead by the uplink's minimum latency (see above)
    keep_ledger: bool = False  # radios keep every frame's fate (memory grows with the run: tests only)
    profile: bool = False  # accumulate per-part wall time in Emulator.timing_s (benchmarks)
    radio_cuts: tuple[Outage, ...] = ()  # every radio frame offered inside these windows is dropped
    mocap_cuts: tuple[Outage, ...] = ()  # no mocap frame is published inside these windows
    # CRTP on each vehicle's zenoh keys (link.keys crtp_uplink / crtp_downlink), with the crazyflie firmware and
    # a keyed connection, in either clock (a cflib client through link.crtp.zenoh_driver)
    crtp_keys: bool = True
    # CRTP for cflib clients over UDP (simulator.crtp_service): vehicle N answers on udp 127.0.0.1:crtp_base_port+N-1
    # (CrazySim's convention: the first at 19850), realtime clock and crazyflie firmware only; None: off
    crtp_base_port: int | None = None
    crtp_host: str = "127.0.0.1"
    crtp_required: bool = True  # False (the CLI's default port): a taken port is a warning, not an error
    crtp_radio: RadioProfile | None = None  # the CRTP radio's; None: `radio`'s
    # the onboard positioning deck: with CRTP on, each mocap frame also reaches the vehicle's estimator at
    # its release time, as a Lighthouse or Loco deck's fix would, unless a ground station streams extpose
    position_deck: bool = True
    # A fresh Signing with the key of `signing` (one per vehicle, for GroundFrameGate's own replay state).
    # None with signing on: the gate can only require signed frames from the ground station's system id.
    signing_factory: Callable[[], object | None] | None = None

    @property
    def crtp_radio_profile(self) -> RadioProfile:
        return self.crtp_radio if self.crtp_radio is not None else self.radio

    def check(self) -> None:
        """One-line UserError for settings no emulator can run with."""
        if isinstance(self.vehicles, bool) or not isinstance(self.vehicles, int) \
                or not 1 <= self.vehicles <= MAX_VEHICLES:
            raise UserError(f"vehicles: {self.vehicles!r} is not a vehicle count 1..{MAX_VEHICLES}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise UserError(f"seed: {self.seed!r} is not a non-negative integer")
        if self.clock not in ("lockstep", "realtime"):
            raise UserError(f"clock: '{self.clock}' is not one of lockstep, realtime")
        rate = self.physics_rate_hz
        if not isinstance(rate, (int, float)) or not math.isfinite(rate) or rate <= 0.0:
            raise UserError(f"physics rate: {rate!r} is not a positive number of Hz")
        if self.duration_s is not None and not (math.isfinite(self.duration_s) and self.duration_s > 0.0):
            raise UserError(f"duration: {self.duration_s!r} is not a positive number of seconds")
        if self.crtp_base_port is not None:
            if not 1 <= self.crtp_base_port <= 65535 - self.vehicles + 1:
                raise UserError(f"crtp port: {self.crtp_base_port!r} leaves no UDP port for each of "
                                f"{self.vehicles} vehicle(s) (1..65535)")
            if self.clock != "realtime" or self.firmware != "crazyflie":
                raise UserError("crtp: cflib clients are served over UDP with --clock realtime and --firmware "
                                "crazyflie (turn it off with --crtp-port off)")
        if self.radio_link is not None:
            check_radio_link(self.radio_link, self.vehicles, self.clock)
        starts = self.start_positions_enu_m
        if starts is not None and len(starts) != self.vehicles:
            raise UserError(f"{len(starts)} start positions given for {self.vehicles} vehicle(s)")
        for outage in self.radio_cuts:
            outage.check("radio cut")
        for outage in self.mocap_cuts:
            outage.check("mocap cut")
