"""link.crtp against Bitcraze's cflib itself: its encoders make the packets our decoders read, and its TOC
element parsers read the items our TOCs give (cflib is the client every Crazyflie script uses)."""

from __future__ import annotations

import math
import struct

import pytest

pytest.importorskip("cflib", reason="cflib is in the test extra (pip install -e '.[test]')")
from cflib.crazyflie.commander import Commander  # noqa: E402
from cflib.crazyflie.high_level_commander import HighLevelCommander  # noqa: E402
from cflib.crazyflie.localization import Localization  # noqa: E402
from cflib.crazyflie.log import LogTocElement  # noqa: E402
from cflib.crazyflie.param import ParamTocElement  # noqa: E402
from cflib.crazyflie.supervisor import Supervisor  # noqa: E402

from link.crtp import setpoints  # noqa: E402
from link.crtp.packet import CRTP_MAX_DATA, CrtpPacket, Port, decode, encode, is_null  # noqa: E402
from link.crtp.toc import Toc, TocEntry  # noqa: E402


class _Platform:
    def __init__(self, protocol: int):
        self.protocol = protocol

    def get_protocol_version(self) -> int:
        return self.protocol


class CapturingCrazyflie:
    """What cflib's commanders need of a Crazyflie: send_packet (captured) and the protocol version (12: what
    the emulator reports, firmware CRTP_PROTOCOL_VERSION; below 8 cflib sends the legacy setpoint types)."""

    def __init__(self, protocol: int = 12):
        self.sent: list[CrtpPacket] = []
        self.platform = _Platform(protocol)

    def send_packet(self, pk, expected_reply=(), resend=False, timeout=0.2) -> None:  # noqa: ARG002
        self.sent.append(decode(bytes((pk.header,)) + bytes(pk.data)))

    def add_port_callback(self, port, cb) -> None:
        pass

    def last(self):
        return setpoints.decode_command(self.sent[-1])


def test_packet_header_and_limits():
    assert encode(CrtpPacket(Port.LOG, 1, b"\x05")) == b"\x5d\x05"  # cflib's log reset: header 0x5D
    assert decode(b"\x5d\x05") == CrtpPacket(5, 1, b"\x05")
    assert decode(b"\x51\x05") == CrtpPacket(5, 1, b"\x05")  # legacy bits clear, as the firmware may send
    assert decode(b"") is None and decode(bytes(32)) is None  # empty; 31 bytes of payload
    assert decode(bytes(31)) is not None
    assert is_null(b"\xff") and is_null(b"\xf3") and not is_null(b"\xfd")
    with pytest.raises(ValueError):
        encode(CrtpPacket(Port.LOG, 1, bytes(CRTP_MAX_DATA + 1)))


def test_commander_packets_decode_to_what_cflib_sent():
    cf = CapturingCrazyflie()
    commander = Commander(cf)
    commander.send_setpoint(2.5, -3.0, 45.0, 38000)
    rpyt = cf.last()
    assert rpyt.roll_deg == 2.5 and rpyt.pitch_deg == 3.0  # cflib sends -pitch: the firmware's legacy sign
    assert rpyt.yaw_rate_dps == 45.0 and rpyt.thrust == 38000
    commander.send_stop_setpoint()
    assert isinstance(cf.last(), setpoints.StopSetpoint)
    commander.send_position_setpoint(1.0, 2.0, 0.5, 90.0)
    assert cf.last() == setpoints.PositionSetpoint(1.0, 2.0, 0.5, 90.0)
    commander.send_notify_setpoint_stop()
    assert isinstance(cf.last(), setpoints.NotifySetpointsStop)
    commander.send_hover_setpoint(0.25, -0.5, 30.0, 0.4)
    assert vars(cf.last()) == pytest.approx(vars(setpoints.Hover(0.25, -0.5, 30.0, 0.4)))  # float32 on the wire
    commander.send_velocity_world_setpoint(0.5, 0.25, -0.25, -10.0)
    assert vars(cf.last()) == vars(setpoints.VelocityWorld(0.5, 0.25, -0.25, -10.0))  # exact in float32
    commander.send_setpoint_manual(1.0, 2.0, 3.0, 50.0, False)
    # cflib negates pitch (the legacy sign, as for RPYT) and maps 0..100 % onto PWM 10001..60000
    assert cf.last() == setpoints.Manual(1.0, -2.0, 3.0, 35000, False)
    commander.send_setpoint_manual(-10.0, 20.0, 0.0, 100.0, True)
    assert cf.last() == setpoints.Manual(-10.0, -20.0, 0.0, 60000, True)


def test_legacy_setpoints_of_old_firmware_decode_with_the_yaw_rate_turned():
    """cflib speaks the legacy types to firmware of protocol < 8; their decoders negate the yaw rate, so the
    same call means the same motion on either firmware."""
    old, new = CapturingCrazyflie(protocol=7), CapturingCrazyflie()
    for cf in (old, new):
        commander = Commander(cf)
        commander.send_velocity_world_setpoint(0.5, 0.25, -0.25, -10.0)
        commander.send_zdistance_setpoint(2.0, -4.0, 30.0, 0.5)
        commander.send_hover_setpoint(0.25, -0.5, 30.0, 0.4)
    assert [p.data[0] for p in old.sent] == [1, 2, 5] and [p.data[0] for p in new.sent] == [8, 9, 10]
    for legacy, current in zip(old.sent, new.sent, strict=True):
        assert setpoints.decode_command(legacy) == setpoints.decode_command(current)


def test_cppm_and_altitude_hold_packets():
    """No cflib call sends these (RC transmitters and old clients do); the layouts of crtp_commander_generic.c."""
    packet = CrtpPacket(Port.GENERIC_SETPOINT, 0, struct.pack("<BBHHHHH", 3, 1, 1600, 1400, 1500, 1750, 1200))
    assert setpoints.decode_command(packet) == setpoints.CppmEmulation(1600, 1400, 1500, 1750, (1200,))
    short_aux = CrtpPacket(Port.GENERIC_SETPOINT, 0, struct.pack("<BBHHHH", 3, 2, 1500, 1500, 1500, 1000))
    assert isinstance(setpoints.decode_command(short_aux), setpoints.Malformed)  # says 2 aux, carries none
    hold = CrtpPacket(Port.GENERIC_SETPOINT, 0, struct.pack("<Bffff", 4, 1.0, -2.0, 5.0, 0.25))
    assert setpoints.decode_command(hold) == setpoints.AltitudeHold(1.0, -2.0, 5.0, 0.25)


def test_high_level_and_localization_and_supervisor_packets():
    cf = CapturingCrazyflie()
    hl = HighLevelCommander(cf)
    hl.takeoff(0.75, 2.5)
    takeoff = cf.last()
    assert (takeoff.kind, takeoff.z_m, takeoff.duration_s, takeoff.use_current_yaw) == ("takeoff", 0.75, 2.5, False)
    hl.takeoff(0.75, 2.5, yaw=None)
    assert cf.last().use_current_yaw  # yaw None: "use the current yaw"
    hl.go_to(0.5, -0.25, 1.0, 0.5, 3.0, relative=True)
    go = cf.last()
    assert (go.kind, go.x_m, go.y_m, go.z_m, go.yaw_rad, go.duration_s, go.relative) == \
        ("go_to", 0.5, -0.25, 1.0, 0.5, 3.0, True)
    hl.land(0.0, 2.0, yaw=1.0)
    land = cf.last()
    assert (land.kind, land.z_m, land.yaw_rad, land.use_current_yaw) == ("land", 0.0, 1.0, False)
    hl.stop()
    assert cf.last().kind == "stop"
    loc = Localization(cf)
    loc.send_extpose((1.0, 2.0, 3.0), (0.0, 0.0, 0.6, 0.8))
    pose = cf.last()
    assert (pose.x_m, pose.y_m, pose.z_m) == (1.0, 2.0, 3.0)
    assert pose.attitude_wxyz == pytest.approx((0.8, 0.0, 0.0, 0.6))  # cflib sends x, y, z, w
    loc.send_extpos((1.0, 2.0, 3.0))
    assert cf.last() == setpoints.ExternalPosition(1.0, 2.0, 3.0, None)
    supervisor = Supervisor(cf)
    supervisor.send_arming_request(True)
    assert cf.last() == setpoints.SupervisorRequest("arm")
    supervisor.send_arming_request(False)
    assert cf.last() == setpoints.SupervisorRequest("disarm")


def test_malformed_and_non_finite_payloads_are_named_not_raised():
    for packet in (CrtpPacket(Port.COMMANDER, 0, b"\x00" * 13), CrtpPacket(Port.GENERIC_SETPOINT, 0, b""),
                   CrtpPacket(Port.GENERIC_SETPOINT, 0, b"\x07" + bytes(15)),
                   CrtpPacket(Port.GENERIC_SETPOINT, 0, b"\x63"), CrtpPacket(Port.HIGH_LEVEL, 0, b"\x07\x00"),
                   CrtpPacket(Port.LOCALIZATION, 0, bytes(5)), CrtpPacket(Port.SUPERVISOR, 1, b"\x01")):
        assert isinstance(setpoints.decode_command(packet), setpoints.Malformed), packet
    nan = setpoints.decode_command(CrtpPacket(Port.COMMANDER, 0, struct.pack("<fffH", math.nan, 0, 0, 0)))
    assert math.isnan(nan.roll_deg)  # decoded as sent: the firmware side refuses it (tests/simulator)
    assert setpoints.decode_command(CrtpPacket(Port.CONSOLE, 0, b"hi")) is None


def test_toc_items_parse_in_cflibs_own_elements():
    log = Toc("log", [TocEntry("stateEstimate", "x", "float"), TocEntry("motor", "m1", "uint16_t")])
    param = Toc("param", [TocEntry("pid_rate", "roll_kp", "float"),
                          TocEntry("locSrv", "extPosStdDev", "float", read_only=True),
                          TocEntry("commander", "enHighLevel", "uint8_t")])
    for toc, element in ((log, LogTocElement), (param, ParamTocElement)):
        info = toc.info()
        assert info[0] == 3 and struct.unpack_from("<HI", info, 1) == (len(toc.entries), toc.crc)
        for index, entry in enumerate(toc.entries):
            item = toc.item(index)
            assert len(item) <= CRTP_MAX_DATA and struct.unpack_from("<H", item, 1)[0] == index
            parsed = element(index, item[3:])  # what cflib's toc.py hands the element: after cmd and index
            assert (parsed.group, parsed.name, parsed.ctype) == (entry.group, entry.name, entry.type_name)
        assert toc.item(len(toc.entries)) == b"\x02"  # out of range: the command byte alone, as log.c does
    assert ParamTocElement(1, param.item(1)[3:]).get_readable_access() == "RO"
    assert ParamTocElement(0, param.item(0)[3:]).get_readable_access() == "RW"
    changed = Toc("log", [TocEntry("stateEstimate", "y", "float"), TocEntry("motor", "m1", "uint16_t")])
    assert changed.crc != log.crc  # a changed TOC invalidates cflib's cache (keyed by the CRC)


def test_full_state_and_z_distance_decode_as_the_firmware_does():
    cf = CapturingCrazyflie()
    commander = Commander(cf)
    q = (0.0, 0.0, math.sin(0.4), math.cos(0.4))  # x, y, z, w: yaw 0.8 rad
    commander.send_full_state_setpoint((0.1, -0.2, 0.75), (0.3, 0.0, 0.0), (0.0, 0.0, 1.0), q, 0.0, 0.0, 0.5)
    full = cf.last()
    assert full.position_m == (0.1, -0.2, 0.75) and full.velocity_mps == (0.3, 0.0, 0.0)
    assert full.acceleration_mps2 == (0.0, 0.0, 1.0) and full.rates_radps == (0.0, 0.0, 0.5)  # mrad/s on the wire
    w, x, y, z = full.attitude_wxyz
    assert math.isclose(math.hypot(w, x, y, z), 1.0)
    assert abs(2.0 * math.atan2(z, w) - 0.8) < 0.01  # 9-bit components: a few mrad
    commander.send_zdistance_setpoint(3.0, -2.0, 20.0, 0.4)
    assert vars(cf.last()) == pytest.approx(vars(setpoints.ZDistance(3.0, -2.0, 20.0, 0.4)))
    assert setpoints.decompress_quaternion(0xC0000000) == (1.0, 0.0, 0.0, 0.0)  # [0, 0, 0, 1] (cflib docs)
