"""model.air_budget against the nRF24L01+ time on air written out by hand (Product Specification 6.1.7, 7.3):
T_oa = (8 (preamble 1 + address 5 + payload + CRC 2) + 9 control bits) / 2 Mbit/s, 130 us settling before
every transmission and every acknowledgement, the downlink riding on acknowledgements."""

from __future__ import annotations

import dataclasses

import pytest

from model.air_budget import air_budget, packets
from model.radio import load_radio_profile

LINK = load_radio_profile("crazyradio").crazyradio
CLEAN = dataclasses.replace(LINK, packet_loss_probability=0.0)


def t_oa_s(payload_bytes: int) -> float:
    return (8 * (1 + 5 + payload_bytes + 2) + 9) / 2e6


def test_a_frame_is_cut_into_crtp_packets_of_30_data_bytes():
    assert packets(LINK, [(10.0, 280)]) == [(90.0, 30), (10.0, 10)]  # 9 full packets and the rest, per frame
    assert packets(LINK, [(5.0, 30)]) == [(5.0, 30)]


def test_the_downlink_rides_on_the_uplinks_acknowledgements():
    budget = air_budget(CLEAN, [(100.0, 14)], [(100.0, 28)], usb_transactions_per_s=1000.0)
    assert budget.transactions_per_s == 100.0
    by_hand = 100 * (130e-6 + t_oa_s(1 + 14) + 130e-6 + t_oa_s(1 + 28))
    assert budget.air_s_per_s == pytest.approx(by_hand, rel=1e-12) and budget.usb_load == pytest.approx(0.1)


def test_more_downlink_than_uplink_costs_null_packets_to_poll_it():
    budget = air_budget(CLEAN, [(100.0, 14)], [(300.0, 28)], usb_transactions_per_s=1000.0)
    assert budget.transactions_per_s == 300.0
    sends = 100 * t_oa_s(1 + 14) + 200 * t_oa_s(1)  # 200 CRTP null packets (the header alone)
    by_hand = 300 * 2 * 130e-6 + sends + 300 * t_oa_s(1 + 28)
    assert budget.air_s_per_s == pytest.approx(by_hand, rel=1e-12)


def test_lost_attempts_add_their_send_and_the_retransmit_delay():
    clean = air_budget(CLEAN, [(100.0, 14)], [], usb_transactions_per_s=1000.0)
    lossy = air_budget(dataclasses.replace(CLEAN, packet_loss_probability=0.2), [(100.0, 14)], [], 1000.0)
    failed_attempt = 130e-6 + t_oa_s(1 + 14) + 500e-6  # settle, send, wait ARD for an ACK that never comes
    assert lossy.air_s_per_s - clean.air_s_per_s == pytest.approx(100 * 0.25 * failed_attempt, rel=1e-12)
    assert not air_budget(CLEAN, [(1500.0, 14)], [], usb_transactions_per_s=1000.0).fits  # USB-bound
