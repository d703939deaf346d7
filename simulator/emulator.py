"""The emulator: simulated Crazyflies behind simulated radios, answering on zenoh.

Takes in: an EmulatorConfig (vehicle, mocap room, radio profile, world, number of vehicles, seed,
clock, connection); uplink MAVLink frames on each vehicle's uplink key (through the vehicle's uplink
radio); CRTP packets on its crtp/uplink key (faithful firmware; through its CRTP radio; simulator.fleet);
lockstep acknowledgements on the clock-ack keys (link.clock).
Gives out: downlink frames (through the downlink radio), CRTP answers and log blocks on crtp/downlink,
mocap poses (ground network, no radio), simulation-only ground truth, lockstep clock ticks (keys:
link.keys.VehicleKeys, one set per vehicle id 1..N); `summary()` (one line), `radio_report()`
(per-channel statistics, the frames the fault windows cut, the uplink parser's counters - signature
failures included - and, with keep_ledger, every frame's fate), and per-part timing with
`profile=True` (for benchmarks).

Parts: the fleet (simulator.fleet: each vehicle with its radios and codecs), publishing
(simulator.publishing), fault injection (simulator.faults), the lockstep clock and its lookahead
(simulator.lockstep); this module runs them on one simulation clock, in realtime or lockstep, and reports.

Clocks: `realtime` paces physics by the monotonic wall clock; `lockstep` advances simulation time
only when every ground station taking part has acknowledged the previous tick, so a run depends on
the seed and on what the ground stations send, never on scheduling. Without a ground station the
lockstep clock stands still (and says so every WAIT_LOG_PERIOD_S).
"""

from __future__ import annotations

import json
import math
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from link.transports.zenoh_process import use_lockstep_settings
from model.errors import UserError
from simulator.emulator_config import EmulatorConfig
from simulator.fleet import STEP_TOTAL, VehicleNode, default_starts
from simulator.lockstep import LockstepClock
from simulator.profiling import time_parts

__all__ = ["Emulator", "EmulatorConfig"]

REALTIME_MAX_SLEEP_S = 0.05  # the realtime loop never sleeps longer than this (keeps Ctrl-C prompt)
# The timed parts inside a vehicle step (simulator.fleet, simulator.vehicle_sim): a step's time beyond
# them is the routing between them.
STEP_PARTS = ("radio", "decode", "outputs", "encode", "uplink", "firmware", "sensors", "physics")


class Emulator:
    """N VehicleNodes on one simulation clock. `with Emulator(config) as emu: emu.run()`."""

    def __init__(self, config: EmulatorConfig):
        config.check()
        self.config = config
        seeds = np.random.SeedSequence(config.seed).spawn(config.vehicles)
        starts = config.start_positions_enu_m or default_starts(config.world, config.vehicles, config.airborne)
        use_lockstep_settings(config.clock == "lockstep")  # before the nodes open zenoh (zenoh_process)
        self.nodes = [VehicleNode(config, i + 1, seeds[i], starts[i]) for i in range(config.vehicles)]
        self.dt_s = 1.0 / config.physics_rate_hz
        self.steps = 0  # physics steps done (lockstep: may run ahead of the last tick, see simulator.lockstep)
        self.stopped = False
        self.wall_start = time.monotonic()
        self.timing_s: dict[str, float] = defaultdict(float)  # transport parts, with config.profile
        # the run ends at the step boundary nearest the duration
        self.duration_steps = (None if config.duration_s is None
                               else max(1, math.ceil(config.duration_s / self.dt_s - 0.5)))
        self.lockstep = LockstepClock(self)
        if config.profile:
            time_parts(self, {"flush": "send"}, self.timing_s)

    @property
    def t_s(self) -> float:
        """Simulation time of the physics (s); in lockstep, possibly ahead of the last tick."""
        return self.steps * self.dt_s

    @property
    def tick(self) -> int:
        """The last lockstep tick published (-1: none yet)."""
        return self.lockstep.tick

    @property
    def tick_steps(self) -> int:
        """The step count of the last lockstep tick."""
        return self.lockstep.tick_steps

    @property
    def tick_time_s(self) -> float:
        """Simulation time of the last tick published (s): what the ground stations have seen."""
        return self.lockstep.tick_time_s

    def __enter__(self) -> Emulator:
        try:
            for node in self.nodes:
                node.open(self.config)
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        for node in self.nodes:
            node.close()

    def step_all(self) -> None:
        self.steps += 1
        n = self.steps
        for node in self.nodes:
            node.step(n)

    def run(self) -> None:
        self.wall_start = time.monotonic()
        if self.config.clock == "realtime":
            self.run_realtime()
        else:
            self.lockstep.run()

    def duration_reached(self, steps: int) -> bool:
        return self.duration_steps is not None and steps >= self.duration_steps

    # --- realtime -------------------------------------------------------------------------------
    def run_realtime(self) -> None:
        """Step at the wall clock's pace; uplink frames enter the radio at the current sim time."""
        start = time.monotonic()
        while not self.stopped and not self.duration_reached(self.steps):
            for node in self.nodes:
                node.receive_uplink(self.t_s)
                if node.crtp is not None:
                    node.receive_crtp(self.t_s)
            self.step_all()
            for node in self.nodes:
                node.outbox.send(node.outbox.take_due(self.steps))
            lag = start + self.t_s - time.monotonic()
            if lag > 0:
                time.sleep(min(lag, REALTIME_MAX_SLEEP_S))

    def flush(self, step_no: int) -> None:
        """Publish every vehicle's frames stamped at or before step_no."""
        for node in self.nodes:
            outbox = node.outbox
            if outbox.queue:
                outbox.send(outbox.take_due(step_no))

    # --- reports --------------------------------------------------------------------------------
    def summary(self) -> str:
        now = time.monotonic()
        wall = now - self.wall_start
        sim_s = self.tick_time_s if self.config.clock == "lockstep" else self.t_s
        running = now - (self.lockstep.first_tick_wall or self.wall_start)  # lockstep: from the first tick
        rtf = sim_s / running if running > 0 else 0.0
        parts = [f"emulator: stopped at t={sim_s:.3f} s simulated ({wall:.1f} s wall, {rtf:.3f}x real time), "
                 f"{len(self.nodes)} vehicle(s), seed {self.config.seed}"]
        if self.config.clock == "lockstep":
            parts[0] += f", {self.tick + 1} ticks"
        for node in self.nodes:
            up, down = node.uplink_radio.stats, node.downlink_radio.stats
            crash = "ok"
            if node.sim.crash is not None:
                c = node.sim.crash
                crash = f"crashed at t={c.time_s:.3f} s at ({', '.join(f'{v:.2f}' for v in c.position_enu_m)}) m"
            line = (f"v{node.vehicle_id}: uplink {up.delivered}/{up.offered} delivered, "
                    f"downlink {down.delivered}/{down.offered}, rejected {node.sim.firmware.rejected_commands}")
            c = node.parser.counters
            if self.config.signing is not None or c.signature_failures:
                line += (f", signature failures {c.signature_failures} ({c.unsigned_rejected} unsigned, "
                         f"{c.bad_signatures} bad, {c.replays_rejected} replayed)")
            if node.uplink_foreign:
                line += f", {node.uplink_foreign} foreign uplink samples"
            if self.config.radio_cuts:
                line += f", radio cut {node.cut['uplink']} up / {node.cut['downlink']} down"
            if self.config.mocap_cuts:
                line += f", mocap cut {node.mocap_cut}"
            if node.crtp is not None:
                up, down = node.crtp_uplink_radio.stats, node.crtp_downlink_radio.stats
                line += (f", {node.crtp.describe()} (radio: up {up.delivered}/{up.offered}, down "
                         f"{down.delivered}/{down.offered} delivered/offered, {node.crtp_lost} given up)")
            parts.append(f"{line}, {crash}")
        return "; ".join(parts)

    def radio_report(self) -> dict:
        """Per vehicle and direction: the radio's counters, `cut` (frames a radio cut dropped before
        the radio: not in offered, dropped or the ledger) and, with keep_ledger, every offered frame's
        fate [offered_s, bytes, drop cause or null, [delivery_s...]] in offer order. Per vehicle also:
        `uplink_parser` (the vehicle's frame parser counters: frames_ok, crc_failures, unsigned_rejected,
        bad_signatures, replays_rejected, signature_failures, ...), `uplink_foreign` (uplink samples
        not from the ground station, see GroundFrameGate) and `mocap_cut`."""
        report = {"seed": self.config.seed, "radio": self.config.radio.name,
                  "crtp_radio": self.config.crtp_radio_profile.name, "vehicles": {}}
        for node in self.nodes:
            entry = {}
            for name, radio in (("uplink", node.uplink_radio), ("downlink", node.downlink_radio)):
                s = radio.stats
                entry[name] = {
                    "offered": s.offered, "delivered": s.delivered, "duplicated": s.duplicated,
                    "corrupted": s.corrupted, "dropped": {str(cause): count for cause, count in s.dropped.items()},
                    "dropped_total": s.dropped_total, "pending": radio.pending, "cut": node.cut[name],
                    "ledger": [[f.offered_s, f.size_bytes, f.drop_cause and str(f.drop_cause), list(f.delivery_s)]
                               for f in radio.ledger] if radio.keep_ledger else None,
                }
            entry["rejected_commands"] = node.sim.firmware.rejected_commands
            entry["uplink_parser"] = node.parser.counters.as_dict()
            entry["uplink_foreign"] = node.uplink_foreign
            entry["mocap_cut"] = node.mocap_cut
            entry["crash"] = None if node.sim.crash is None else {
                "time_s": node.sim.crash.time_s, "position_enu_m": list(node.sim.crash.position_enu_m),
                "reason": node.sim.crash.reason}
            report["vehicles"][str(node.vehicle_id)] = entry
        return report

    def write_radio_report(self, path: str | Path) -> None:
        try:
            Path(path).write_text(json.dumps(self.radio_report()))
        except OSError as err:
            raise UserError(f"{path}: cannot write the radio report ({err.strerror})") from None

    def timing_report(self) -> dict[str, float]:
        """Seconds spent per part (with config.profile): the vehicles' own split (uplink handling,
        firmware, sensors, physics), radio, encode/decode, routing (what a vehicle step spends beyond
        its timed parts), and the transport's send, poll and wait."""
        total: dict[str, float] = defaultdict(float)
        for node in self.nodes:
            for timing in (node.sim.timing_s, node.timing_s):
                for name, seconds in timing.items():
                    total[name] += seconds
        for name, seconds in self.timing_s.items():
            total[name] += seconds
        step_total = total.pop(STEP_TOTAL, 0.0)
        if step_total:
            total["route"] = step_total - sum(total[part] for part in STEP_PARTS)
        return dict(total)
