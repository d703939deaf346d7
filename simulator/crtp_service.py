"""The emulated Crazyflie's CRTP services: what an unmodified cflib client talks to (`udp://127.0.0.1:19850`).

Takes in: CRTP datagrams from a client (link.crtp.packet), with the vehicle's simulation time; the
vehicle (its firmware's estimate, sensors, motors and battery, which the log variables read and the
parameters write); `due(t)` calls for the log blocks.
Gives out: exactly one reply to every request cflib waits on (it does not retry over UDP), log block
packets at their periods, and the commanding records (link.crtp.setpoints) queued for the firmware
like any uplink message (SimVehicle.handle_uplink: taken at its next 500 Hz cycle); counters of what
was malformed or ignored (`counters`). Nothing a packet holds can raise out of here.

Services (crazyflie-firmware crtpservice.c, platformservice.c, log.c, param_logic.c, mem.c; cflib 0.1.34):
- link (15): echo (0), the "Bitcraze Crazyflie" source name (1), null packets answered with a null packet
  (cflib's scan takes any answer as a Crazyflie);
- platform (13): protocol version 12, firmware and device strings; channel 0 commands are taken, not
  answered (the firmware sends nothing back either); the app channel (2) with cfstack's packets
  (link.crtp.appchannel: thrust + moment for the firmware's force-torque path, time sync answered with the
  vehicle's clock), as if the app that reads them were built in;
- memory (4): no memories;
- log (5): TOC V2 of LOG_VARIABLES, block create/append/delete/start/stop/reset, data on channel 2 with
  a millisecond u24 timestamp of the vehicle's clock;
- param (2): TOC V2 of PARAMETERS, read, write (echoed with the value taken: a value the emulated firmware
  cannot take, such as another controller, is echoed back as the value it kept);
- commander (3), generic setpoints (7), localization (6), high-level commander (8), supervisor (9):
  decoded into records for the firmware; the supervisor's state query is answered here.
"""

from __future__ import annotations

import errno
import math
import struct
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

from link.crtp import appchannel, setpoints
from link.crtp.packet import CRTP_MAX_DATA, CrtpPacket, Port, decode, encode, is_null
from link.crtp.toc import CMD_TOC_INFO, CMD_TOC_ITEM, LOG_MAX_BLOCKS, LOG_TYPE_NAMES, TYPES, Toc, TocEntry
from link.messages import ThrustMoment, TimeSync

PROTOCOL_VERSION = 12  # firmware crtp.h CRTP_PROTOCOL_VERSION (cflib uses the supervisor port from 12)
LINK_SOURCE = b"Bitcraze Crazyflie"  # crtpservice.c linkSource
FIRMWARE_STRING = b"cfstack-emulated"
DEVICE_STRING = b"CF21"  # the Crazyflie 2.1 cfstack emulates (platform_cf2.c device type string)
NULL_REPLY = b"\xff"
# the counters of packets counted and ignored (never answered with anything but what cflib waits for)
IGNORED_COUNTS = ("malformed", "unknown", "unknown_toc_id", "unsupported", "non_finite", "param_refused",
                  "log_errors")
LOG_DATA_CHANNEL = 2
LOG_HEADER_BYTES = 4  # block id + u24 timestamp
LOG_PERIOD_UNIT_S = 0.010  # start's period byte counts 10 ms (cflib LogConfig.period)
# log control commands (log.py)
LOG_DELETE, LOG_START, LOG_STOP, LOG_RESET, LOG_CREATE, LOG_APPEND = 2, 3, 4, 5, 6, 7
# supervisor state bits (supervisor.py)
BIT_CAN_BE_ARMED, BIT_IS_ARMED, BIT_IS_AUTO_ARMED, BIT_CAN_FLY, BIT_IS_FLYING, BIT_IS_CRASHED = 0, 1, 2, 3, 4, 7
BIT_HL_CONTROL_ACTIVE, BIT_HL_TRAJ_FINISHED = 8, 9


def _item(attr: str, index: int) -> Callable:
    """Getter of fw.<attr>[index]."""
    return lambda fw: getattr(fw, attr)[index]


def _position(index: int) -> Callable:
    return lambda fw: fw.position.p[index]


def _velocity(index: int) -> Callable:
    return lambda fw: fw.position.v[index]


def _rpy(index: int) -> Callable:
    return lambda fw: fw.estimate_rpy_deg[index]


# (group, name, type, getter of the CrazyflieFirmware): the firmware's names and units (stabilizer.c,
# sensors, pm, power_distribution): stateEstimate in m, m/s and deg (pitch in the firmware's legacy sign),
# gyro in deg/s, acc in g, kalman.varP* in m^2, pm.vbat in V, motor.m1..m4 in PWM units
LOG_VARIABLES: tuple[tuple[str, str, str, Callable], ...] = (
    *(("stateEstimate", axis, "float", _position(i)) for i, axis in enumerate("xyz")),
    *(("stateEstimate", f"v{axis}", "float", _velocity(i)) for i, axis in enumerate("xyz")),
    *(("stateEstimate", angle, "float", _rpy(i)) for i, angle in enumerate(("roll", "pitch", "yaw"))),
    *(("stateEstimate", f"q{axis}", "float", _item("fusion_q", i)) for i, axis in enumerate("wxyz")),
    *(("stabilizer", angle, "float", _rpy(i)) for i, angle in enumerate(("roll", "pitch", "yaw"))),
    *(("gyro", axis, "float", _item("gyro_dps", i)) for i, axis in enumerate("xyz")),
    *(("acc", axis, "float", _item("acc_g", i)) for i, axis in enumerate("xyz")),
    *(("kalman", f"varP{axis.upper()}", "float", _item("position_variance_m2", i)) for i, axis in enumerate("xyz")),
    ("pm", "vbat", "float", lambda fw: fw.battery.voltage_v),
    ("pm", "batteryLevel", "uint8_t", lambda fw: round(100.0 * fw.battery.charge_left)),  # %
    *(("motor", f"m{i + 1}", "uint16_t", _item("motor_pwm", i)) for i in range(4)),
)


@dataclass
class Param:
    entry: TocEntry
    get: Callable[[], float | int]
    set: Callable[[float | int], None] | None = None  # None: read-only


def _pid_params(group: str, pids) -> list[Param]:
    out = []
    for axis, pid in zip(("roll", "pitch", "yaw"), pids, strict=True):
        for gain in ("kp", "ki", "kd"):
            out.append(Param(TocEntry(group, f"{axis}_{gain}", "float"),
                             (lambda p=pid, g=gain: getattr(p, g)),
                             (lambda v, p=pid, g=gain: setattr(p, g, float(v)))))
    return out


def make_params(fw) -> list[Param]:
    """The parameters cflib scripts commonly touch, bound to the emulated firmware's live values."""
    fixed = Param  # a parameter whose only possible value is the emulated firmware's

    def keep(_value) -> None:
        """Writable on a Crazyflie, but the emulator has one choice: the echo says what it kept."""

    def set_high_level(value) -> None:
        fw.high_level_enabled = bool(value)

    def reset_estimation(value) -> None:
        if value:
            fw.position.reset()

    return [
        fixed(TocEntry("stabilizer", "controller", "uint8_t"), lambda: 1, keep),  # 1 = PID (the one emulated)
        fixed(TocEntry("stabilizer", "estimator", "uint8_t"), lambda: 1, keep),  # 1 = complementary
        Param(TocEntry("commander", "enHighLevel", "uint8_t"), lambda: int(fw.high_level_enabled), set_high_level),
        # estimator_kalman.c: 1 resets the position estimate, and the estimator sets it back to 0
        Param(TocEntry("kalman", "resetEstimation", "uint8_t"), lambda: 0, reset_estimation),
        # crtp_commander_rpyt.c: each RPYT axis an angle (1) or a rate (0); defaults roll, pitch 1, yaw 0
        *(Param(TocEntry("flightmode", f"stabMode{axis.title()}", "uint8_t"),
                (lambda a=axis: fw.rpyt.stab_mode[a]),
                (lambda v, a=axis: fw.rpyt.stab_mode.__setitem__(a, 1 if v else 0)))
          for axis in ("roll", "pitch", "yaw")),
        *_pid_params("pid_attitude", fw.controller.attitude.attitude),
        *_pid_params("pid_rate", fw.controller.attitude.rate),
        Param(TocEntry("locSrv", "extPosStdDev", "float", read_only=True), lambda: fw.cf.ext_pos_std_m),
        Param(TocEntry("locSrv", "extQuatStdDev", "float", read_only=True), lambda: fw.cf.ext_quat_std_rad),
    ]


@dataclass(frozen=True, slots=True)
class CrtpDatagram:
    """One CRTP packet the radio delivered, queued for the vehicle's next firmware cycle
    (SimVehicle.handle_uplink), where its `crtp` services answer it."""

    data: bytes


@dataclass
class LogBlock:
    variables: list[tuple[int, str]]  # (log TOC index, fetch type name)
    period_s: float = 0.0
    next_s: float | None = None  # None: stopped


class CrtpService:
    """One vehicle's CRTP endpoint logic (no socket: simulator.fleet feeds it datagrams)."""

    def __init__(self, sim):
        self.sim = sim
        self.fw = sim.firmware
        # supervisor.info (supervisor.c infoBitfield, the bits of the state query) reads the service's clock
        entries = [TocEntry(g, n, t) for g, n, t, _ in LOG_VARIABLES] + [TocEntry("supervisor", "info", "uint16_t")]
        self.log_toc = Toc("log", entries)
        self._log_getters = [get for *_, get in LOG_VARIABLES] + [lambda fw: self._state_bits(self._now_s)]
        self._now_s = 0.0
        self.params = make_params(self.fw)
        self.param_toc = Toc("param", [p.entry for p in self.params])
        self.blocks: dict[int, LogBlock] = {}
        self.last_extpos_s = -math.inf  # when the last extpos / extpose was taken
        self.counters: Counter[str] = Counter()

    def describe(self) -> str:
        """One phrase for the emulator's summary: packets served and what was ignored."""
        c = self.counters
        ignored = ", ".join(f"{c[k]} {k.replace('_', ' ')}" for k in IGNORED_COUNTS if c[k])
        return f"crtp {c['packets']} packets" + (f" ({ignored} ignored)" if ignored else "")

    # --- requests ---------------------------------------------------------------------------------
    def handle(self, datagram: bytes, t_s: float) -> list[bytes]:
        """The replies to one datagram (usually one; none for what the firmware does not answer)."""
        if is_null(datagram):
            return [NULL_REPLY]
        packet = decode(datagram)
        if packet is None:
            self.counters["malformed"] += 1
            return []
        self.counters["packets"] += 1
        try:
            replies = self._dispatch(packet, t_s)
        except (struct.error, IndexError, ValueError, OverflowError):
            self.counters["malformed"] += 1
            return []
        return [encode(CrtpPacket(packet.port, channel, data)) for channel, data in replies]

    def _dispatch(self, packet: CrtpPacket, t_s: float) -> list[tuple[int, bytes]]:
        port, channel, data = packet.port, packet.channel, packet.data
        if port == Port.LINK:
            return self._link(channel, data)
        if port == Port.PLATFORM:
            return self._platform(channel, data, t_s)
        if port == Port.MEM:
            return [(0, b"\x01\x00")] if channel == 0 and data[:1] == b"\x01" else self._unknown("mem request")
        if port == Port.LOG:
            return self._log(channel, data, t_s)
        if port == Port.PARAM:
            return self._param(channel, data)
        record = setpoints.decode_command(packet)
        if record == setpoints.SupervisorRequest("state"):  # answered here: the firmware has nothing to do
            return [(0, bytes((0x80 | setpoints.SUPERVISOR_STATE,)) + struct.pack("<H", self._state_bits(t_s)))]
        if record is None:
            return self._unknown(f"port {port}")
        if isinstance(record, setpoints.Malformed):
            self.counters["malformed"] += 1
            return []
        if isinstance(record, setpoints.Unsupported):
            self.counters["unsupported"] += 1
            return []
        if not _finite_record(record):
            self.counters["non_finite"] += 1
            return []
        self.sim.handle_uplink(record, t_s)
        if isinstance(record, setpoints.ExternalPosition):
            self.last_extpos_s = t_s  # a ground station streams the position: the positioning deck stands aside
        if isinstance(record, setpoints.SupervisorRequest) and record.kind in ("arm", "disarm"):
            # (command | 0x80, success, armed): what the arming will give at the firmware's next cycle
            armed = record.kind == "arm" and self.fw.mode.name != "CRASHED"
            success = record.kind == "disarm" or armed
            return [(1, bytes((0x81, int(success), int(armed))))]
        return []

    def _unknown(self, what: str) -> list:
        self.counters["unknown"] += 1
        return []

    def _link(self, channel: int, data: bytes) -> list[tuple[int, bytes]]:
        if channel == 0:
            return [(0, data)]  # echo (cflib's latency ping)
        if channel == 1:
            return [(1, LINK_SOURCE.ljust(CRTP_MAX_DATA, b"\0"))]
        return self._unknown("link channel")

    def _platform(self, channel: int, data: bytes, t_s: float) -> list[tuple[int, bytes]]:
        if channel == 1 and data:
            answers = {0: struct.pack("<i", PROTOCOL_VERSION), 1: FIRMWARE_STRING, 2: DEVICE_STRING}
            if data[0] in answers:
                return [(1, bytes((data[0],)) + answers[data[0]])]
        if channel == 0 and data:
            return []  # platform commands (continuous wave, notifications): taken, never answered
        if channel == appchannel.APP_CHANNEL:
            return self._app(data, t_s)
        return self._unknown("platform request")

    def _app(self, data: bytes, t_s: float) -> list[tuple[int, bytes]]:
        message = appchannel.decode(data, from_vehicle=False)
        if message is None:
            return self._unknown("app-channel packet")
        if isinstance(message, setpoints.Malformed):
            self.counters["malformed"] += 1
            return []
        if isinstance(message, TimeSync):  # answered with the vehicle's clock (usecTimestamp), >= 1 ns
            reply = TimeSync(remote_ns=max(1, round(t_s * 1e9)), origin_ns=message.origin_ns)
            return [(appchannel.APP_CHANNEL, appchannel.encode_time_sync(reply, reply=True))]
        if not all(math.isfinite(v) for v in (message.thrust_n, *message.moment_flu_nm)):
            self.counters["non_finite"] += 1
            return []
        self.sim.handle_uplink(ThrustMoment(t_s, message.thrust_n, message.moment_flu_nm), t_s)
        return []

    def _toc(self, toc: Toc, data: bytes) -> list[tuple[int, bytes]]:
        if data[0] == CMD_TOC_INFO:
            return [(0, toc.info())]
        if data[0] == CMD_TOC_ITEM and len(data) == 3:
            index = struct.unpack_from("<H", data, 1)[0]
            if index >= len(toc.entries):
                self.counters["unknown_toc_id"] += 1
            return [(0, toc.item(index))]
        return self._unknown(f"{toc.kind} TOC command")

    # --- log ----------------------------------------------------------------------------------------
    def _log(self, channel: int, data: bytes, t_s: float) -> list[tuple[int, bytes]]:
        if channel == 0:
            return self._toc(self.log_toc, data)
        if channel != 1 or not data:
            return self._unknown("log channel")
        cmd = data[0]
        if cmd == LOG_RESET:
            self.blocks.clear()
            return [(1, bytes((cmd, 0, 0)))]
        block_id = data[1]
        if cmd in (LOG_CREATE, LOG_APPEND):
            error = self._add_variables(cmd, block_id, data[2:])
        elif cmd == LOG_DELETE:
            error = 0 if self.blocks.pop(block_id, None) is not None else errno.ENOENT
        elif cmd == LOG_START:
            error = self._start(block_id, data[2] * LOG_PERIOD_UNIT_S, t_s)
        elif cmd == LOG_STOP:
            block = self.blocks.get(block_id)
            error = errno.ENOENT if block is None else 0
            if block is not None:
                block.next_s = None
        else:
            return self._unknown("log command")
        if error:
            self.counters["log_errors"] += 1
        return [(1, bytes((cmd, block_id, error)))]

    def _add_variables(self, cmd: int, block_id: int, spec: bytes) -> int:
        if len(spec) % 3:
            return errno.E2BIG
        variables = []
        for i in range(0, len(spec), 3):
            fetch = LOG_TYPE_NAMES.get(spec[i] & 0x0F)
            index = struct.unpack_from("<H", spec, i + 1)[0]
            if fetch is None or index >= len(self.log_toc.entries):
                self.counters["unknown_toc_id"] += 1
                return errno.ENOENT
            variables.append((index, fetch))
        if cmd == LOG_CREATE:
            if block_id in self.blocks:
                return errno.EEXIST
            if len(self.blocks) >= LOG_MAX_BLOCKS:
                return errno.ENOMEM
            block = self.blocks[block_id] = LogBlock([])
        else:
            block = self.blocks.get(block_id)
            if block is None:
                return errno.ENOENT
        size = sum(struct.calcsize(TYPES[f][2]) for _, f in block.variables + variables)
        if LOG_HEADER_BYTES + size > CRTP_MAX_DATA:
            if cmd == LOG_CREATE:
                del self.blocks[block_id]
            return errno.E2BIG
        block.variables.extend(variables)
        return 0

    def _start(self, block_id: int, period_s: float, t_s: float) -> int:
        block = self.blocks.get(block_id)
        if block is None:
            return errno.ENOENT
        if period_s <= 0.0:
            return errno.EINVAL
        block.period_s = period_s
        block.next_s = t_s + period_s
        return 0

    def due(self, t_s: float) -> list[bytes]:
        """Log data packets of every running block due by t_s (each block at most once per call)."""
        out = []
        self._now_s = t_s
        for block_id, block in self.blocks.items():
            if block.next_s is None or t_s + 1e-9 < block.next_s:
                continue
            block.next_s += block.period_s * max(1, math.floor((t_s - block.next_s) / block.period_s + 1e-9) + 1)
            stamp_ms = int(round(t_s * 1000.0)) & 0xFFFFFF
            payload = bytes((block_id,)) + stamp_ms.to_bytes(3, "little")
            for index, fetch in block.variables:
                payload += _pack(fetch, self._log_getters[index](self.fw))
            out.append(encode(CrtpPacket(Port.LOG, LOG_DATA_CHANNEL, payload)))
        return out

    # --- params -------------------------------------------------------------------------------------
    def _param(self, channel: int, data: bytes) -> list[tuple[int, bytes]]:
        if channel == 0:
            return self._toc(self.param_toc, data)
        if channel not in (1, 2) or len(data) < 2:
            return self._unknown("param request")
        index = struct.unpack_from("<H", data, 0)[0]
        if index >= len(self.params):
            self.counters["unknown_toc_id"] += 1
            return [] if channel == 2 else [(1, data[:2] + b"\x01")]  # read: an error status
        param = self.params[index]
        if channel == 1:  # read: index, status 0, value
            return [(1, data[:2] + b"\x00" + param.entry.pack(param.get()))]
        value = param.entry.unpack(data[2:])
        if param.set is None or value is None or (isinstance(value, float) and not math.isfinite(value)):
            self.counters["param_refused"] += 1
            return []  # the firmware answers no write to a read-only parameter
        param.set(value)
        return [(2, data[:2] + param.entry.pack(param.get()))]  # the echo carries the value now held

    # --- supervisor ---------------------------------------------------------------------------------
    def _state_bits(self, t_s: float) -> int:
        fw = self.fw
        crashed = fw.mode.name == "CRASHED"
        bits = 0 if crashed else (1 << BIT_CAN_BE_ARMED | 1 << BIT_CAN_FLY)
        if fw.armed:
            bits |= 1 << BIT_IS_ARMED | 1 << BIT_IS_AUTO_ARMED
        if fw.armed and any(fw.motor_pwm):
            bits |= 1 << BIT_IS_FLYING
        if crashed:
            bits |= 1 << BIT_IS_CRASHED
        if fw.high_level.plan is not None:
            bits |= 1 << BIT_HL_CONTROL_ACTIVE
        if fw.high_level.finished(t_s):
            bits |= 1 << BIT_HL_TRAJ_FINISHED
        return bits


def _pack(type_name: str, value) -> bytes:
    """value in a log type, integers clamped to the type's range (a C cast would wrap: clamping is kinder)."""
    fmt = TYPES[type_name][2]
    if fmt == "<f":
        return struct.pack(fmt, float(value))
    bits = struct.calcsize(fmt) * 8
    unsigned = fmt[1].isupper()
    low, high = (0, 2 ** bits - 1) if unsigned else (-(2 ** (bits - 1)), 2 ** (bits - 1) - 1)
    return struct.pack(fmt, min(max(int(value), low), high))


def _finite_record(record) -> bool:
    values = [v for v in vars(record).values() if isinstance(v, float)]
    attitude = getattr(record, "attitude_wxyz", None)
    if attitude is not None:
        values.extend(attitude)
    return all(math.isfinite(v) for v in values)
