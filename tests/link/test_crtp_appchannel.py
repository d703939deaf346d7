"""cfstack's app-channel packets (link.crtp.appchannel): within one CRTP packet, exact round trips, and what
is not ours or is cut short is named, never raised; the calibrated N -> PWM map of the Crazyflie link."""

from __future__ import annotations

import struct

import pytest

from link.crtp import appchannel
from link.crtp.cflib_link import CrtpLinkSettings
from link.crtp.packet import CRTP_MAX_DATA
from link.crtp.setpoints import Malformed
from link.messages import ThrustMoment, TimeSync


def test_thrust_moment_and_time_sync_fit_one_packet_and_come_back_as_sent():
    command = ThrustMoment(12.345678, 0.3125, (0.001, -0.0025, 0.0005))
    payload = appchannel.encode_thrust_moment(command)
    assert len(payload) <= CRTP_MAX_DATA
    back = appchannel.decode(payload, from_vehicle=False)
    assert back.time_s == pytest.approx(12.345678, abs=1e-6) and back.thrust_n == pytest.approx(0.3125)
    assert back.moment_flu_nm == pytest.approx(command.moment_flu_nm, rel=1e-6)  # float32 on the wire
    request = TimeSync(remote_ns=0, origin_ns=1_234_567_890_123)
    assert appchannel.decode(appchannel.encode_time_sync(request, reply=False), from_vehicle=False) == request
    reply = TimeSync(remote_ns=987_654_321, origin_ns=1_234_567_890_123)
    assert appchannel.decode(appchannel.encode_time_sync(reply, reply=True), from_vehicle=True) == reply


def test_other_apps_packets_and_short_ones_are_named_not_raised():
    assert appchannel.decode(b"", from_vehicle=False) is None
    assert appchannel.decode(b"\x7fhello", from_vehicle=False) is None  # another app's: not ours to judge
    assert isinstance(appchannel.decode(b"\x01" + bytes(10), from_vehicle=False), Malformed)
    assert isinstance(appchannel.decode(b"\x02" + bytes(3), from_vehicle=True), Malformed)
    # a vehicle never sends a thrust command: from the vehicle it is not one of ours
    assert appchannel.decode(struct.pack("<BIffff", 1, 0, 0, 0, 0, 0), from_vehicle=True) is None


def test_the_n_to_pwm_map_is_the_firmwares_compensated_thrust_and_stays_within_rpyt():
    settings = CrtpLinkSettings(imu_period_ms=10, status_period_ms=100, per_motor_max_n=0.12, pwm_full=65535,
                                rpyt_max_pwm=60000, unlock_after_silence_s=0.5, land_duration_per_m_s=3.0,
                                connect_timeout_s=1.0)
    assert settings.thrust_pwm(4 * 0.12 / 2) == round(65535 / 2)  # half of full thrust: half of the PWM range
    assert settings.thrust_pwm(10.0) == 60000 and settings.thrust_pwm(-1.0) == 0
    assert settings.thrust_pwm(float("nan")) == 0
