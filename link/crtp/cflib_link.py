"""The ground station's radio to a Crazyflie, through Bitcraze's cflib: cfstack messages over CRTP.

Takes in: a cflib URI (`radio://0/80/2M/E7E7E7E7E7` with a Crazyradio, `udp://127.0.0.1:19850` for the
emulator or CrazySim, `zenoh://cfstack/1` for the emulator on zenoh (link.crtp.zenoh_driver); any link
driver cflib has), whether it flies in lockstep (zenoh:// only), CrtpLinkSettings (groundstation/params/crtp_link.toml),
a clock (s) to stamp what arrives; cfstack messages to send.
Gives out: cfstack messages received (ImuSample from a log block of acc and gyro, Heartbeat and
BatteryStatus from one of supervisor.info and pm.*, TimeSync replies from the app channel), as an
Endpoint of link.endpoint gives them (`transport.receive()` then `deliver()` -> link.messages.Received),
and LinkStats of both directions.

What each message becomes on the wire (all stock firmware unless marked):
- AttitudeTarget -> the RPYT setpoint (cflib `commander.send_setpoint`): roll and pitch (deg, FLU; cflib
  turns pitch into the firmware's legacy sign), the heading (deg, absolute: the link sets
  flightmode.stabModeYaw = 1 at connect), thrust in PWM from the calibrated map
  PWM = T / (4 per_motor_max_n) * pwm_full, at most the commander's 60000. After a silence the first
  setpoint is preceded by one with thrust 0, which unlocks the firmware's thrust lock.
- ThrustMoment -> cfstack's app-channel packet (link.crtp.appchannel; needs the app on a real Crazyflie).
- TimeSync request -> the app-channel time sync (no answer from a stock Crazyflie: then there is no clock
  offset and no latency compensation).
- ExternalPose -> extpose (localization, `loc.send_extpose`), the mocap pose for the onboard estimator.
- VehicleCommand ARM / DISARM -> the supervisor's arming request; LAND -> the high-level commander's
  land at the floor; REBOOT has no CRTP command over a link (logged, not sent).
- Heartbeat (the ground station's) and PositionTarget are not sent: CRTP has no heartbeat, and position
  mode is flown by a cflib script itself (README).
Received: the log blocks carry the vehicle's millisecond clock; the IMU's acc (g) and gyro (deg/s) are
turned into m/s^2 and rad/s (FLU, as the firmware's body frame is). The heartbeat's armed, crashed and
landing (the high-level commander flying our LAND) are the supervisor's bits.

cflib runs its own threads: callbacks put messages in a queue under a lock; the flight loop takes them.

Lockstep (zenoh:// only). Connecting - TOCs, parameters, the heading mode, the log blocks - is over
before the ground station joins the lockstep, and the emulator answers it off the air (simulator.fleet),
so a flight starts the same whatever the scheduling. Then the zenoh driver is gated: the flight loop
takes the CRTP samples a tick announces (`receive`: raw packets, counted), lets cflib's thread have
exactly those, and waits until it has handled them (`deliver`), so the tick's messages are those of its
packets only. Nothing else may send on its own: cflib's 10 Hz latency ping (its link statistics, wall
clock in its payload and its timing) is not started, and the zenoh driver needs no resend timers.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from link.crtp import appchannel
from link.messages import (
    AttitudeTarget,
    BatteryStatus,
    CommandKind,
    ExternalPose,
    Heartbeat,
    ImuSample,
    Received,
    ThrustMoment,
    TimeSync,
    VehicleCommand,
    VehicleMode,
)
from link.stats import LinkStats
from link.transports.base import TransportStats
from model.errors import UserError
from model.frames import euler_zyx_of

log = logging.getLogger("cfstack.crtp")

G_MPS2 = 9.81  # the firmware's gravity (physicalConstants.h): acc.* are in units of it
IMU_VARIABLES = ("acc.x", "acc.y", "acc.z", "gyro.x", "gyro.y", "gyro.z")
STATUS_VARIABLES = ("supervisor.info", "pm.vbat", "pm.batteryLevel")
# supervisor.info bits (supervisor.c, cflib supervisor.py)
BIT_IS_ARMED, BIT_IS_FLYING, BIT_IS_CRASHED, BIT_IS_LOCKED, BIT_HL_CONTROL_ACTIVE = 1, 4, 7, 6, 8
VEHICLE_SYSTEM_ID = 1  # Received.system_id: CRTP has none; a link is one vehicle
MS_WRAP = 1 << 24  # log timestamps are a u24 of milliseconds
CONNECT_RETRY_S = 0.2  # between connection attempts


@dataclass(frozen=True)
class CrtpLinkSettings:
    imu_period_ms: int
    status_period_ms: int
    per_motor_max_n: float
    pwm_full: int
    rpyt_max_pwm: int
    unlock_after_silence_s: float
    land_duration_per_m_s: float
    connect_timeout_s: float

    def thrust_pwm(self, thrust_n: float) -> int:
        """The RPYT thrust of a collective thrust (N), within 0..rpyt_max_pwm."""
        pwm = thrust_n / (4.0 * self.per_motor_max_n) * self.pwm_full
        return int(min(max(round(pwm), 0), self.rpyt_max_pwm)) if math.isfinite(pwm) else 0


class _TransportView:
    """The transport face of a CrazyflieRadio: its counters, receive() and close()."""

    scheme = "crtp"

    def __init__(self, radio: CrazyflieRadio):
        self.radio = radio

    @property
    def stats(self) -> TransportStats:
        """Lockstep: the zenoh driver's packet counts (what the clock's acks and ticks count); else the radio's."""
        return self.radio.driver.stats if self.radio.gated else self.radio.tx

    @property
    def is_open(self) -> bool:
        return self.radio.is_open

    def receive(self, timeout_s: float = 0.0) -> list:
        return self.radio.receive(timeout_s)

    def close(self) -> None:
        self.radio.close()

    def describe(self) -> str:
        return f"crtp:{self.radio.uri}"


class CrazyflieRadio:
    """An Endpoint over cflib (link.endpoint's interface). `open()` connects and asks for the log blocks."""

    def __init__(self, uri: str, settings: CrtpLinkSettings, clock: Callable[[], float], lockstep: bool = False):
        self.uri = uri
        self.lockstep = lockstep
        self.protocol = "crtp"  # VehicleLink: a lockstep tick counts this radio's samples as CRTP
        self.settings = settings
        self.clock = clock
        self.stats = LinkStats()
        self.tx = TransportStats()
        self.transport = _TransportView(self)  # what VehicleLink reads of an Endpoint's transport
        self.is_open = False
        self.gated = False  # lockstep: cflib gets only the packets a tick releases (zenoh driver gate)
        self.reports_uplink_count = False  # a Crazyflie does not count what it received
        self._cf = None
        self._queue: deque = deque()
        self._arrived = threading.Condition()
        self._received = 0
        self._last_setpoint_s = -math.inf
        self._last_z_m: float | None = None  # the newest extpose height (LAND's duration)
        self._ms_base = 0  # unwrapping the u24 millisecond clock
        self._last_ms = None

    # --- the transport side (VehicleLink) ------------------------------------------------------
    def open(self) -> None:
        """Connect through cflib, retrying until connect_timeout_s (a vehicle just switched on, an emulator
        still starting), one line naming the URI if nothing answers; then ask for the log blocks, set the
        heading mode."""
        import cflib.crtp

        from link.crtp import zenoh_driver

        if self.uri.startswith(zenoh_driver.SCHEME):
            zenoh_driver.parse_uri(self.uri)  # a malformed one is one line now, not a connect that never answers
        elif self.lockstep:
            raise UserError(f"crtp: '{self.uri}' cannot fly in lockstep: only zenoh:// can (udp:// and radio:// "
                            "fly in realtime)")
        # cflib logs each failed attempt with its traceback: the one line below says it instead
        logging.getLogger("cflib").setLevel(logging.ERROR)
        cflib.crtp.init_drivers()
        zenoh_driver.register()
        deadline = time.monotonic() + self.settings.connect_timeout_s
        while True:
            cf, failure = self._connect(deadline)
            if cf is not None:
                break
            if time.monotonic() >= deadline:
                raise UserError(f"crtp: cannot connect to {self.uri} ({failure.strip().splitlines()[0]})")
            time.sleep(CONNECT_RETRY_S)
        self._cf = cf
        self.is_open = True
        cf.appchannel.packet_received.add_callback(self._on_app_packet)
        answered = [self._set_param("flightmode.stabModeYaw", 1),  # the RPYT yaw field is a heading
                    self._start_log("cfstack.imu", IMU_VARIABLES, self.settings.imu_period_ms, self._on_imu),
                    self._start_log("cfstack.status", STATUS_VARIABLES, self.settings.status_period_ms,
                                    self._on_status)]
        if self.lockstep:  # everything asked is answered before the flight (its first tick) starts
            deadline = time.monotonic() + self.settings.connect_timeout_s
            if not all(event.wait(max(0.0, deadline - time.monotonic())) for event in answered):
                raise UserError(f"crtp: {self.uri} did not confirm the heading mode and log blocks in "
                                f"{self.settings.connect_timeout_s:g} s")
            self.driver.gate(self.settings.connect_timeout_s)
            self.gated = True
        log.info("crtp: connected to %s", self.uri)

    @property
    def driver(self):
        """cflib's link driver of the connection (link.crtp.zenoh_driver.ZenohDriver in lockstep)."""
        return self._cf.link

    def _set_param(self, name: str, value) -> threading.Event:
        """Set a parameter; the event is set when the Crazyflie confirms it."""
        group, _, short = name.partition(".")
        confirmed = threading.Event()
        self._cf.param.add_update_callback(group=group, name=short, cb=lambda _name, _value: confirmed.set())
        self._cf.param.set_value(name, value)
        return confirmed

    def _connect(self, deadline: float):
        """(the connected Crazyflie, None) or (None, why not) after one attempt."""
        from cflib.crazyflie import Crazyflie

        cf = Crazyflie(rw_cache=None)
        if self.lockstep:  # no wall-clock ping in a lockstep flight (module docstring); an instance's own no-op
            cf.link_statistics.start = lambda: None
        done, failure = threading.Event(), []
        cf.fully_connected.add_callback(lambda _uri: done.set())
        cf.connection_failed.add_callback(lambda _uri, msg: (failure.append(str(msg)), done.set()))
        cf.connection_lost.add_callback(self._on_lost)
        try:
            cf.open_link(self.uri)
        except Exception as err:  # noqa: BLE001 - a driver's own error (bad URI, no dongle): one line
            return None, f"{type(err).__name__}: {err}"
        if done.wait(max(0.0, deadline - time.monotonic())) and not failure:
            return cf, ""
        stats = getattr(cf.link, "stats", None)  # the zenoh driver counts what went each way
        counted = "" if stats is None else f": {stats.frames_sent} packets sent, {stats.chunks_received} received"
        cf.close_link()
        return None, failure[0] if failure else f"no answer in {self.settings.connect_timeout_s:g} s{counted}"

    def _start_log(self, name: str, variables, period_ms: int, callback) -> threading.Event:
        """Create and start a log block; the event is set when the Crazyflie confirms the start."""
        from cflib.crazyflie.log import LogConfig

        config = LogConfig(name=name, period_in_ms=period_ms)
        for variable in variables:
            config.add_variable(variable)
        try:
            self._cf.log.add_config(config)
        except (KeyError, AttributeError) as err:
            raise UserError(f"crtp: {self.uri} cannot log {', '.join(variables)} ({err})") from None
        config.data_received_cb.add_callback(callback)
        started = threading.Event()
        config.started_cb.add_callback(lambda _config, ok: ok and started.set())
        config.start()
        return started

    def close(self) -> None:
        if self._cf is not None and self.is_open:
            self.is_open = False
            try:
                self._cf.commander.send_stop_setpoint()
            finally:
                self._cf.close_link()

    def receive(self, timeout_s: float = 0.0) -> list:
        """Every message that arrived (undecoded records: deliver() stamps them), waiting at most timeout_s.
        Lockstep: the raw packets that arrived, held from cflib until deliver()."""
        if self.gated:
            return self.driver.fetch(timeout_s) if self.is_open else []
        with self._arrived:
            if not self._queue and timeout_s > 0.0:
                self._arrived.wait(timeout_s)
            taken = list(self._queue)
            self._queue.clear()
        self.tx.chunks_received += len(taken)
        return taken

    def deliver(self, chunks: list) -> list[Received]:
        """Stamp what receive() took with the clock now, counting it (CRTP has no sequence numbers: the radio's
        link layer retries instead, so nothing is counted lost). Lockstep: `chunks` are raw packets; cflib
        handles them first, and what its callbacks made of them is stamped."""
        if self.gated:
            self.driver.release(len(chunks))
            self.driver.wait_handled(self.settings.connect_timeout_s)
            with self._arrived:
                chunks = list(self._queue)
                self._queue.clear()
        now = self.clock()
        out = []
        for message, size in chunks:
            sequence = self._received % 256
            self._received += 1
            self.stats.record_frame(VEHICLE_SYSTEM_ID, 1, sequence, size, now, getattr(message, "time_s", None))
            out.append(Received(message, VEHICLE_SYSTEM_ID, sequence, now))
        return out

    def _put(self, message, size: int) -> None:
        with self._arrived:
            self._queue.append((message, size))
            self._arrived.notify()

    # --- what arrives (cflib's thread) ----------------------------------------------------------------
    def _vehicle_time_s(self, stamp_ms: int) -> float:
        if self._last_ms is not None and stamp_ms < self._last_ms:
            self._ms_base += MS_WRAP
        self._last_ms = stamp_ms
        return (self._ms_base + stamp_ms) / 1000.0

    def _on_imu(self, stamp_ms: int, data: dict, _config) -> None:
        acc = tuple(data[f"acc.{a}"] * G_MPS2 for a in "xyz")
        gyro = tuple(math.radians(data[f"gyro.{a}"]) for a in "xyz")
        self._put(ImuSample(self._vehicle_time_s(stamp_ms), acc, gyro), 4 + 24)

    def _on_status(self, stamp_ms: int, data: dict, _config) -> None:
        bits = int(data["supervisor.info"])
        crashed = bool(bits >> BIT_IS_CRASHED & 1 or bits >> BIT_IS_LOCKED & 1)
        mode = (VehicleMode.CRASHED if crashed else VehicleMode.LANDING if bits >> BIT_HL_CONTROL_ACTIVE & 1
                else VehicleMode.ATTITUDE if bits >> BIT_IS_FLYING & 1 else VehicleMode.IDLE)
        self._put(Heartbeat(armed=bool(bits >> BIT_IS_ARMED & 1), mode=mode), 4 + 7)
        self._put(BatteryStatus(voltage_v=float(data["pm.vbat"]), remaining_pct=int(data["pm.batteryLevel"])), 0)

    def _on_app_packet(self, data: bytes) -> None:
        message = appchannel.decode(bytes(data), from_vehicle=True)
        if isinstance(message, TimeSync):
            self._put(message, len(data))

    def _on_lost(self, _uri, msg) -> None:
        if self.is_open:  # cflib's message may carry a traceback: its first line says it
            why = str(msg).strip().splitlines()[0] if str(msg).strip() else "no reason given"
            log.warning("crtp: the link to %s was lost (%s)", self.uri, why)

    # --- what is sent ---------------------------------------------------------------------------------
    def send(self, message, target_system: int = 0) -> bytes:  # noqa: ARG002 - Endpoint's signature
        """Send one cfstack message as its CRTP packet (see the module docstring); returns b"" (cflib frames it)."""
        cf = self._cf
        if cf is None or not self.is_open:
            self.stats.record_sent(0, False)
            return b""
        sent = self._send(cf, message)
        if sent:
            self.tx.frames_sent += 1
            self.stats.record_sent(sent)
        return b""

    def _send(self, cf, message) -> int:
        """The payload bytes sent for message (0: nothing sent)."""
        if isinstance(message, AttitudeTarget):
            return self._send_attitude(cf, message)
        if isinstance(message, ThrustMoment):
            self._last_setpoint_s = message.time_s
            cf.appchannel.send_packet(appchannel.encode_thrust_moment(message))
            return 21
        if isinstance(message, ExternalPose):
            w, x, y, z = message.attitude_wxyz
            cf.loc.send_extpose(list(message.position_enu_m), [x, y, z, w])
            self._last_z_m = message.position_enu_m[2]
            return 29
        if isinstance(message, TimeSync):
            cf.appchannel.send_packet(appchannel.encode_time_sync(message, reply=False))
            return 9
        if isinstance(message, VehicleCommand):
            return self._send_command(cf, message)
        return 0  # the ground station's heartbeat, a position target: nothing on CRTP

    def _send_attitude(self, cf, message: AttitudeTarget) -> int:
        roll, pitch, yaw = (math.degrees(a) for a in euler_zyx_of(message.attitude_wxyz))
        sent = 0
        if message.time_s - self._last_setpoint_s > self.settings.unlock_after_silence_s:
            cf.commander.send_setpoint(0.0, 0.0, yaw, 0)  # thrust 0: the firmware's thrust lock opens
            sent += 14
        self._last_setpoint_s = message.time_s
        cf.commander.send_setpoint(roll, pitch, yaw, self.settings.thrust_pwm(message.thrust_n))
        return sent + 14

    def _send_command(self, cf, message: VehicleCommand) -> int:
        if message.kind in (CommandKind.ARM, CommandKind.DISARM):
            cf.supervisor.send_arming_request(message.kind == CommandKind.ARM)
            return 2
        if message.kind == CommandKind.LAND:
            height = self._last_z_m if self._last_z_m is not None else 1.0
            cf.commander.send_notify_setpoint_stop()
            cf.high_level_commander.land(0.0, max(1.0, height * self.settings.land_duration_per_m_s))
            return 5 + 15
        log.warning("crtp: %s has no CRTP command over a link; not sent", message.kind.name)
        return 0
