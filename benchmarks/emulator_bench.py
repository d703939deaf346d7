"""Benchmark: the emulator in-process and over zenoh in lockstep, with and without lookahead.

Takes in: --seconds of simulated flight per zenoh run, --inprocess-seconds, --vehicles (fleet size),
--radio profile (default esb-duplex, MAVLink's), --repeats per zenoh configuration, --seed.
Gives out (printed), in one run:
  1. emulator only, in-process, no transport: one vehicle hovering on scripted ThrustMoment setpoints
     (500 Hz), physics 1 kHz, firmware, IMU, mocap, truth, both radio channels, MAVLink encode/decode:
     real-time factor and us per physics step, and where a step goes;
  2. the same with --vehicles vehicles;
  3. over zenoh (loopback TCP) in lockstep against a minimal scripted responder in a child process
     (joins, waits for each tick's announced frames, sends one ThrustMoment, acks; loop_bench also has it fly
     a mode's own command, airborne: FLOWN): 500 Hz and 100 Hz
     control ticks, lookahead on and off (baseline = off, candidate = on, ratio printed), best of
     --repeats; then where a tick's time goes (emulator: vehicle, radio, encode/decode, routing,
     transport send / poll / wait; responder: waiting for the tick, for its frames, its own work).
Targets (issue "The emulator"): >= 20x real time in-process for one vehicle; over zenoh lockstep
>= 5x at 500 Hz and >= 20x at 100 Hz. This machine is shared (2 cores): figures move from run to run.

Run: python benchmarks/emulator_bench.py [--seconds 4] [--repeats 3] [--radio lab]
(--radio lab: 20 ms minimum latency, so lookahead can hide all of a tick's physics behind the responder's
turn; esb-duplex's 0.84 ms, rounded up to the vehicle firmware's next 2 ms cycle (when a delivered
command first acts), hides two 1 ms steps per tick. Lookahead only pays when a core is free.)
The responder child is this file: python benchmarks/emulator_bench.py --responder ENDPOINT PERIOD_S SECONDS
[VEHICLE FLOWN EXTPOSE WORK_BEFORE_US WORK_AFTER_US]; the last two (default 0) stand for a ground station's own work
per tick (benchmarks/work_budget.py): a busy wait before its commands (on the lockstep's critical path) and one
after its ack (overlapping the emulator's next step).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from collections import deque
from pathlib import Path

from groundstation.controller import load_gains
from link.clock import NS_PER_S, ClockAck, unpack_tick
from link.keys import GROUND_STATION_SYSTEM_ID, VehicleKeys
from link.mavlink.codec import ActuatorLimits, Codec, FrameParser
from link.messages import AttitudeTarget, CommandKind, ExternalPose, MocapPose, ThrustMoment, VehicleCommand
from link.transports import open_transport
from link.transports.zenoh_process import let_woken_reader_run, use_lockstep_settings
from link.transports.zenoh_session import PrivateEndpoint
from model.firmwares import FIRMWARE_VEHICLES
from model.radio import load_radio_profile
from model.vehicle import GRAVITY_MPS2, load_mocap_room, load_vehicle
from simulator.emulator import Emulator, EmulatorConfig

PHYSICS_RATE_HZ = 1000.0
SETPOINT_RATE_HZ = 500.0  # in-process scripted setpoints
HOVER_HEIGHT_M = 1.0
TARGET_INPROCESS_RTF = 20.0
TARGET_ZENOH_RTF = {500.0: 5.0, 100.0: 20.0}
PREFIX = "cfbench"
MOCAP_SOURCE = 1  # the responder's sources: downlink, mocap, truth
VEHICLE_PARTS = ("uplink", "firmware", "sensors", "physics", "outputs")
EMULATOR_PARTS = ("radio", "encode", "decode", "route")
TRANSPORT_PARTS = ("send", "poll", "wait")
# What the responder flies: FIXED sends one ThrustMoment(weight) per tick, whatever the rate (the floor as
# issue 19 was filed); a mode's name sends that mode's own command, as `cfstack fly --mode M` does, holds the
# height on the mocap poses and, with the faithful firmware, forwards each pose (cfstack fly's default
# --extpose), so that the emulator does a flight's work: its onboard loops of that mode, airborne.
FIXED = "fixed"
FLOWN = (FIXED, "moments", "attitude")
LEVEL_WXYZ = (1.0, 0.0, 0.0, 0.0)


def make_config(radio: str, vehicles: int, seed: int, **changes) -> EmulatorConfig:
    vehicle = load_vehicle(FIRMWARE_VEHICLES[changes.get("firmware", "ideal")])  # the firmware's vehicle
    return EmulatorConfig(vehicle=vehicle, mocap_room=load_mocap_room("vicon"),
                          radio=load_radio_profile(radio), world=None, vehicles=vehicles, seed=seed,
                          physics_rate_hz=PHYSICS_RATE_HZ, airborne=True,
                          start_positions_enu_m=[(0.5 * i, 0.0, HOVER_HEIGHT_M) for i in range(vehicles)],
                          prefix=PREFIX, **changes)


# --- 1 and 2: in-process ------------------------------------------------------------------------------

def fly_inprocess(radio: str, vehicles: int, seconds: float, seed: int, profile: bool) -> dict:
    """Hover every vehicle on scripted ThrustMoment(weight) setpoints pushed into its uplink radio."""
    emulator = Emulator(make_config(radio, vehicles, seed, profile=profile))
    vehicle = emulator.config.vehicle
    ground = Codec(GROUND_STATION_SYSTEM_ID, limits=ActuatorLimits.from_vehicle(vehicle))
    every = round(PHYSICS_RATE_HZ / SETPOINT_RATE_HZ)
    steps = round(seconds * PHYSICS_RATE_HZ)
    published = 0
    clock = time.perf_counter
    script_s = 0.0
    cpu0 = time.process_time()
    start = clock()
    for n in range(steps):
        if n % every == 0:
            t0 = clock()
            t = emulator.t_s
            frames = [ground.encode(ThrustMoment(t, vehicle.weight_n, (0.0, 0.0, 0.0)), node.vehicle_id)
                      for node in emulator.nodes]
            script_s += clock() - t0
            for node, frame in zip(emulator.nodes, frames, strict=True):
                node.push_uplink([frame], t)
        emulator.step_all()
        for node in emulator.nodes:
            published += len(node.outbox.take_due(emulator.steps))
    wall = clock() - start - script_s  # the scripted ground station's encoding is not the emulator's
    cpu = time.process_time() - cpu0 - script_s
    heights = [node.sim.truth.position_enu_m[2] for node in emulator.nodes]
    return {"vehicle_steps": steps * vehicles, "seconds": seconds, "wall_s": wall, "rtf": seconds / wall,
            "cpu_rtf": seconds / cpu,
            "us_per_step": wall / (steps * vehicles) * 1e6, "published": published,
            "timing": emulator.timing_report(), "crashes": sum(n.sim.crash is not None for n in emulator.nodes),
            "height_error_m": max(abs(h - HOVER_HEIGHT_M) for h in heights),
            "uplink_delivered": sum(n.uplink_radio.stats.delivered for n in emulator.nodes)}


def report_inprocess(title: str, timed: dict, profiled: dict) -> None:
    print(f"{title}: {timed['vehicle_steps']} vehicle-steps, {timed['published']} frames published, "
          f"{timed['uplink_delivered']} setpoints delivered, crashes {timed['crashes']}, "
          f"max |z - {HOVER_HEIGHT_M:g} m| {timed['height_error_m']:.2e} m")
    print(f"  real-time factor {timed['rtf']:.1f}x ({timed['us_per_step']:.1f} us per vehicle physics step); "
          f"{timed['cpu_rtf']:.1f}x on process CPU time; ratio to the {TARGET_INPROCESS_RTF:.0f}x target "
          f"(one vehicle): {timed['rtf'] / TARGET_INPROCESS_RTF:.2f}")
    steps = profiled["vehicle_steps"]
    parts = profiled["timing"]
    total = sum(parts.values())
    print(f"  where a step goes (profiled run, {total / steps * 1e6:.1f} us/step with accounting):")
    for name in VEHICLE_PARTS + EMULATOR_PARTS:
        if name in parts:
            print(f"    {name:<9} {parts[name] / steps * 1e6:6.2f} us/step {100 * parts[name] / total:5.1f} %")


# --- 3: over zenoh ----------------------------------------------------------------------------------

def cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def fly_zenoh(radio: str, seconds: float, period_s: float, lookahead: bool, seed: int, profile: bool,
              firmware: str = "ideal", flown: str = FIXED, work_us: tuple[float, float] = (0.0, 0.0)) -> dict:
    """The emulator here (listening), the responder as a child process; wall time from tick 0 (tick 0's
    time.monotonic() in "first_tick_monotonic_s"). `flown`: what the responder sends (FLOWN); `work_us`: its busy
    waits per tick before its commands and after its ack."""
    if flown not in FLOWN:
        raise ValueError(f"flown: {flown!r} is not one of {', '.join(FLOWN)}")
    private = PrivateEndpoint()  # where `cfstack fly` puts its emulator child: the floor is the same layout
    endpoint = private.endpoint
    config = make_config(radio, 1, seed, lookahead=lookahead, profile=profile, duration_s=seconds,
                         zenoh_options={"listen": [endpoint]}, firmware=firmware)
    emulator = Emulator(config)
    with emulator, contextlib.closing(private):
        child = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--responder", endpoint,
                                  repr(period_s), repr(seconds), FIRMWARE_VEHICLES[firmware], flown,
                                  "extpose" if firmware == "crazyflie" else "no-extpose", *map(repr, work_us)],
                                 stdout=subprocess.PIPE, text=True)
        ready = child.stdout.readline()  # its transports are matched with ours: it joins right away
        if ready.strip() != "ready":
            child.kill()
            raise RuntimeError(f"the responder did not start: {ready!r}")
        cpu0, main0 = cpu_s(), time.thread_time()
        emulator.run()  # returns at the duration
        wall = time.monotonic() - emulator.lockstep.first_tick_wall
        cpu, main_cpu = cpu_s() - cpu0, time.thread_time() - main0
        out, _ = child.communicate(timeout=120)
    responder = json.loads(out.strip().splitlines()[-1])
    ticks = emulator.tick + 1
    sim = emulator.nodes[0].sim
    return {"rtf": emulator.tick_time_s / wall, "wall_s": wall, "ticks": ticks, "us_per_tick": wall / ticks * 1e6,
            "first_tick_monotonic_s": emulator.lockstep.first_tick_wall,
            "lookahead_steps": emulator.lockstep.lookahead_steps, "timing": emulator.timing_report(),
            "responder": responder, "cpu_us_per_tick": cpu / ticks * 1e6,
            "main_cpu_us_per_tick": main_cpu / ticks * 1e6,
            "airborne_at_end": sim.crash is None and not sim.dynamics.on_ground}


def report_zenoh(radio: str, seconds: float, repeats: int, seed: int) -> None:
    lookahead_s = load_radio_profile(radio).min_latency_s
    horizon_s = Emulator(make_config(radio, 1, seed)).lockstep.lookahead_horizon_s()  # from tick 0 at t = 0
    print(f"over zenoh, lockstep, radio '{radio}' (uplink minimum latency {lookahead_s * 1e3:.3f} ms: lookahead to "
          f"the firmware cycle {horizon_s * 1e3:.3f} ms after a tick), "
          f"{seconds:g} s simulated per run, best of {repeats}; load average {os.getloadavg()[0]:.1f} "
          f"on {os.cpu_count()} CPUs:")
    for rate_hz in (500.0, 100.0):
        period_s = 1.0 / rate_hz
        best = {}
        runs_of = {False: [], True: []}
        for _ in range(repeats):  # interleaved, so both see the same machine load
            for lookahead in (False, True):
                runs_of[lookahead].append(fly_zenoh(radio, seconds, period_s, lookahead, seed, profile=False))
        for lookahead in (False, True):
            runs = runs_of[lookahead]
            rtfs = [r["rtf"] for r in runs]
            best[lookahead] = max(runs, key=lambda r: r["rtf"])
            r = best[lookahead]
            cpu_us = r["cpu_us_per_tick"] + r["responder"]["cpu_s"] / r["ticks"] * 1e6
            print(f"  {rate_hz:3.0f} Hz tick, lookahead {'on ' if lookahead else 'off'}: {r['rtf']:5.1f}x real time "
                  f"({r['us_per_tick']:.0f} us per tick, {r['ticks']} ticks, median of runs "
                  f"{statistics.median(rtfs):.1f}x, {r['lookahead_steps']} steps run ahead); CPU per tick: "
                  f"emulator {r['cpu_us_per_tick']:.0f} + responder {cpu_us - r['cpu_us_per_tick']:.0f} us "
                  f"(= {period_s * 1e6 / cpu_us:.1f}x if run back to back on one free core)")
        target = TARGET_ZENOH_RTF[rate_hz]
        print(f"    lookahead on / off (candidate / baseline): {best[True]['rtf'] / best[False]['rtf']:.2f}; "
              f"ratio to the {target:.0f}x target: {best[True]['rtf'] / target:.2f}")
        profiled = fly_zenoh(radio, seconds, period_s, True, seed, profile=True)
        report_tick_split(profiled)


def report_tick_split(run: dict) -> None:
    ticks = run["ticks"]
    parts = run["timing"]
    per_tick = {name: seconds / ticks * 1e6 for name, seconds in parts.items()}
    accounted = sum(per_tick.values())
    print(f"    where a tick goes (profiled run, {run['rtf']:.1f}x, {run['us_per_tick']:.0f} us/tick):")
    groups = (("vehicle (physics, firmware, sensors)", VEHICLE_PARTS),
              ("emulator radio, codec, routing", EMULATOR_PARTS),
              ("transport (zenoh put, poll, blocked waiting)", TRANSPORT_PARTS))
    for title, names in groups:
        detail = ", ".join(f"{n} {per_tick.get(n, 0.0):.0f}" for n in names)
        print(f"      {title:<46} {sum(per_tick.get(n, 0.0) for n in names):6.0f} us  ({detail})")
    print(f"      {'unaccounted (loop, GIL, scheduling)':<46} {run['us_per_tick'] - accounted:6.0f} us")
    print(f"      emulator CPU {run['cpu_us_per_tick']:.0f} us/tick, of which its main thread "
          f"{run['main_cpu_us_per_tick']:.0f} us (the rest: zenoh and receiving threads)")
    r = run["responder"]
    rt = r["ticks"]
    print(f"      responder: waiting for the tick {r['tick_wait_s'] / rt * 1e6:.0f} us, for its frames "
          f"{r['frames_wait_s'] / rt * 1e6:.0f} us, its own work {r['work_s'] / rt * 1e6:.0f} us "
          f"(CPU {r['cpu_s'] / rt * 1e6:.0f} us/tick, {r['context_switches'] / rt:.1f} context switches/tick)")


# --- the responder child ------------------------------------------------------------------------------

class HeightHold:
    """The responder's collective thrust holding HOVER_HEIGHT_M on the mocap poses:
    T = m (g + kp_z (z_ref - z) - kd_z v_z), v_z from the last two poses, kp_z and kd_z the lab report's
    (groundstation/params/gains.toml), clipped to the vehicle's thrust range. It keeps the faithful
    firmware's vehicle airborne, whose own draw and battery sag make a fixed thrust sink to the floor."""

    def __init__(self, vehicle) -> None:
        gains = load_gains()
        self.mass_kg, self.max_thrust_n = vehicle.mass_kg, vehicle.max_thrust_n
        self.kp, self.kd = gains.kp[2], gains.kd[2]
        self.thrust_n = vehicle.weight_n
        self._last: tuple[float, float] | None = None  # (time s, z m) of the last pose

    def see(self, pose: MocapPose) -> None:
        t, z = pose.time_s, pose.position_enu_m[2]
        vz = 0.0 if self._last is None or t <= self._last[0] else (z - self._last[1]) / (t - self._last[0])
        self._last = (t, z)
        accel = GRAVITY_MPS2 + self.kp * (HOVER_HEIGHT_M - z) - self.kd * vz
        self.thrust_n = min(max(self.mass_kg * accel, 0.0), self.max_thrust_n)


def busy_wait(seconds: float) -> None:
    """Hold the CPU (and the GIL) for `seconds` of wall time, as a ground station's Python work does."""
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        pass


def responder(endpoint: str, period_s: float, seconds: float, vehicle_name: str = "crazyflie", flown: str = FIXED,
              extpose: str = "no-extpose", work_before_us: float = 0.0, work_after_us: float = 0.0) -> None:
    """Join vehicle 1's lockstep; per tick: wait for the announced frames (blocking on the key still
    short), send ARM (first tick) and the command `flown` says (FLOWN: a hover ThrustMoment of the emulated
    vehicle's weight, or a mode's own command on the height hold, each pose forwarded with "extpose"), ack
    with wake-up = tick + period. Its acks carry the period as a standing order (ClockAck.period_ns), as
    the ground station's do, so the emulator may publish a tick before the last one's ack when its
    lookahead covers a whole tick. `work_before_us` / `work_after_us`: a busy wait per tick before its commands
    and after its ack; with work after the ack it yields its CPU right after the ack, as the ground station's
    lockstep clock does before its bookkeeping (link.transports.zenoh_process.let_woken_reader_run)."""
    opts = {"connect": [endpoint], "listen": []}
    use_lockstep_settings(True)  # as a lockstep ground station's (groundstation.session)
    keys = VehicleKeys(PREFIX, 1)
    vehicle = load_vehicle(vehicle_name)
    codec = Codec(GROUND_STATION_SYSTEM_ID, limits=ActuatorLimits.from_vehicle(vehicle))
    commands = FlownCommands(vehicle, flown, extpose == "extpose", codec)
    sources = [open_transport("zenoh", rx=keys.downlink, **opts), open_transport("zenoh", rx=keys.mocap, **opts),
               open_transport("zenoh", rx=keys.truth, **opts)]
    uplink = open_transport("zenoh", tx=keys.uplink, **opts)
    clock = open_transport("zenoh", tx=keys.clock_ack, rx=keys.clock, **opts)
    clock.wait_for_subscribers(30.0)
    uplink.wait_for_subscribers(30.0)
    print("ready", flush=True)
    counts = [0, 0, 0]
    period_ns = round(period_s * NS_PER_S)
    waits = {"tick_wait_s": 0.0, "frames_wait_s": 0.0, "work_s": 0.0}
    perf = time.perf_counter
    clock.send(ClockAck(-1, 0, 0, period_ns=period_ns).pack())
    ticks, last, cpu0, main0, switches0 = 0, -1, 0.0, 0.0, 0
    queued: deque = deque()  # tick records received ahead of the one being answered
    while True:
        t0 = perf()
        while not queued:
            for data in clock.receive(1.0):
                candidate = unpack_tick(data)
                newest = queued[-1].tick if queued else last
                if candidate is not None and candidate.tick > newest:
                    queued.append(candidate)
        tick = queued.popleft()
        t1 = perf()
        want = (tick.downlink_published, tick.mocap_published, tick.truth_published)
        while True:
            for i, source in enumerate(sources):
                got = source.receive(0.0)
                counts[i] += len(got)
                if i == MOCAP_SOURCE:
                    commands.take_mocap(got)
            short = next((i for i in range(3) if counts[i] < want[i]), None)
            if short is None:
                break
            got = sources[short].receive(0.005)
            counts[short] += len(got)
            if short == MOCAP_SOURCE:
                commands.take_mocap(got)
        t2 = perf()
        if tick.tick == 0:
            uplink.send(codec.encode(VehicleCommand(tick.time_s, CommandKind.ARM), 1))
            cpu0, main0 = cpu_s(), time.thread_time()
            usage = resource.getrusage(resource.RUSAGE_SELF)
            switches0 = usage.ru_nvcsw + usage.ru_nivcsw
        if work_before_us > 0:
            busy_wait(work_before_us * 1e-6)
        for message in commands.tick(tick.time_s):
            uplink.send(codec.encode(message, 1))
        last = tick.tick
        done = tick.time_s >= seconds - 1e-9
        clock.send(ClockAck(tick.tick, uplink.stats.frames_sent, 0 if done else tick.time_ns + period_ns,
                            leaving=done, period_ns=period_ns).pack())
        if work_after_us > 0:
            let_woken_reader_run()
            busy_wait(work_after_us * 1e-6)
        t3 = perf()
        if ticks > 0:
            waits["tick_wait_s"] += t1 - t0
            waits["frames_wait_s"] += t2 - t1
            waits["work_s"] += t3 - t2
        ticks += 1
        if done:
            break
    usage = resource.getrusage(resource.RUSAGE_SELF)
    print(json.dumps({"ticks": ticks, "cpu_s": cpu_s() - cpu0, "main_cpu_s": time.thread_time() - main0,
                      "context_switches": usage.ru_nvcsw + usage.ru_nivcsw - switches0, **waits}), flush=True)
    for transport in (*sources, uplink, clock):
        transport.close()


class FlownCommands:
    """What the responder sends each tick (FLOWN): FIXED, the weight as a ThrustMoment; a mode's name, that
    mode's command on the height hold, after each of the tick's poses forwarded as ExternalPose when
    `forward_poses` (as the ground station's tick sends them)."""

    def __init__(self, vehicle, flown: str, forward_poses: bool, codec: Codec) -> None:
        self.vehicle, self.flown, self.forward_poses = vehicle, flown, forward_poses
        self.hold = None if flown == FIXED else HeightHold(vehicle)
        self._parser = None if self.hold is None else FrameParser(codec)  # the poses, read only to hold the height
        self._mocap: list = []  # the tick's mocap samples, when the height is held

    def take_mocap(self, samples: list) -> None:
        if self.hold is not None:
            self._mocap.extend(samples)

    def tick(self, t: float) -> list:
        """The messages to send at tick time t, in order."""
        if self.hold is None:
            return [ThrustMoment(t, self.vehicle.weight_n, (0.0, 0.0, 0.0))]
        out = []
        for sample in self._mocap:
            for decoded in self._parser.feed(sample, True):
                pose = decoded.message
                if isinstance(pose, MocapPose):
                    self.hold.see(pose)
                    if self.forward_poses:
                        out.append(ExternalPose(pose.time_s, pose.position_enu_m, pose.attitude_wxyz))
        self._mocap.clear()
        thrust_n = self.hold.thrust_n
        out.append(ThrustMoment(t, thrust_n, (0.0, 0.0, 0.0)) if self.flown == "moments"
                   else AttitudeTarget(t, thrust_n, LEVEL_WXYZ))
        return out


RESPONDER_USAGE = "--responder ENDPOINT PERIOD_S SECONDS [VEHICLE FLOWN EXTPOSE WORK_BEFORE_US WORK_AFTER_US]"


def responder_main(argv: list[str]) -> None:
    """The responder child's arguments (RESPONDER_USAGE, the module's docstring: what is left out takes the
    responder's defaults), as fly_zenoh passes them; a wrong list gets one line and exit 1."""
    try:
        if not 3 <= len(argv) <= 8:
            raise ValueError(f"expected 3 to 8 arguments, got {len(argv)}")
        period_s, seconds, *work_us = (float(v) for v in (argv[1], argv[2], *argv[6:8]))
    except ValueError as err:
        sys.exit(f"emulator_bench.py {RESPONDER_USAGE}: {err}")
    responder(argv[0], period_s, seconds, *argv[3:6], *work_us)


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--responder":  # fly_zenoh's child
        responder_main(sys.argv[2:])
        return
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0,
                        help="simulated seconds per zenoh run (longer runs: steadier figures)")
    parser.add_argument("--inprocess-seconds", type=float, default=10.0, help="simulated seconds, in-process")
    parser.add_argument("--vehicles", type=int, default=10, help="fleet size of the second in-process run")
    parser.add_argument("--radio", default="esb-duplex", help="radio profile (name or TOML file)")
    parser.add_argument("--repeats", type=int, default=3, help="runs per zenoh configuration (best is reported)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    for count in (1, args.vehicles):
        seconds = args.inprocess_seconds if count == 1 else max(args.inprocess_seconds / count, 1.0)
        timed = fly_inprocess(args.radio, count, seconds, args.seed, profile=False)
        profiled = fly_inprocess(args.radio, count, seconds, args.seed, profile=True)
        report_inprocess(f"in-process, {count} vehicle(s), radio '{args.radio}', {seconds:g} s simulated",
                         timed, profiled)
    report_zenoh(args.radio, args.seconds, args.repeats, args.seed)


if __name__ == "__main__":
    main()
