"""CRTP across the simulated radio (simulator.fleet.VehicleNode.receive_crtp and step): what the air loses is offered
again, in order, as cflib's radio driver resends until acknowledged, so a lossy radio delays CRTP and loses
none of it; a corrupted copy fails the radio's CRC. And the radio's own signals this rests on: push() says
whether the air lost a frame, pop_due() can discard corrupted copies."""

from __future__ import annotations

import dataclasses

import numpy as np

from link.crtp.packet import CrtpPacket, Port, decode, encode
from link.transports import open_transport
from model.radio import load_radio_profile
from model.vehicle import load_mocap_room, load_vehicle
from simulator.emulator_config import EmulatorConfig
from simulator.fleet import VehicleNode
from simulator.radio import RadioChannel

CF21 = load_vehicle("cf21")


def _lossy(loss: float, base_s: float = 0.002, corrupt: float = 0.0):
    return dataclasses.replace(load_radio_profile("ideal"), loss_probability=loss, base_latency_s=base_s,
                               corrupt_frame_probability=corrupt)


def test_push_says_which_frames_the_air_lost_and_crc_discards_corrupted_copies():
    channel = RadioChannel(_lossy(0.3), np.random.default_rng(4), keep_ledger=True)
    kept = [channel.push(bytes((i % 256,)) * 20, i * 1e-3) for i in range(400)]
    assert kept == [fate.drop_cause is None for fate in channel.ledger] and 0 < kept.count(False) < 200
    corrupting = RadioChannel(_lossy(0.0, corrupt=1.0), np.random.default_rng(4))
    for i in range(10):
        corrupting.push(bytes(20), i * 1e-3)
    assert corrupting.pop_due(1.0, discard_corrupted=True) == [] and corrupting.stats.corrupted == 10


def _node(radio, bus: str) -> VehicleNode:
    config = EmulatorConfig(vehicle=CF21, mocap_room=load_mocap_room("vicon"), radio=radio, world=None, seed=5,
                            clock="realtime", firmware="crazyflie")
    node = VehicleNode(config, 1, np.random.SeedSequence(5), (0.0, 0.0, 0.0))
    node.crtp_link = open_transport(f"mem:{bus}", tx="down", rx="up")
    return node


def test_a_lossy_radio_delays_crtp_in_order_and_loses_none_of_it():
    node = _node(_lossy(0.4), "crtp-lossy")
    client = open_transport("mem:crtp-lossy", tx="up", rx="down")
    sent, echoes = [], []
    for step in range(1, 1001):  # 1 s of realtime steps; an echo request in each of the first 300
        if step <= 300:
            sent.append(encode(CrtpPacket(Port.LINK, 0, step.to_bytes(2, "little"))))
            client.send(sent[-1])
        node.receive_crtp(node.sim.t_s)
        node.step(step)
        echoes += [decode(d).data for d in client.receive(0.0)]
    assert echoes == [decode(p).data for p in sent]  # every one, once, in the order sent
    up = node.crtp_uplink_radio.stats
    assert node.crtp_lost == 0 and up.offered > 300 + 100  # the air lost ~40 %: each was tried again
    client.close()
    node.close()


def test_a_packet_the_air_never_carries_is_given_up_after_cflibs_tries():
    node = _node(_lossy(1.0), "crtp-dead")
    client = open_transport("mem:crtp-dead", tx="up", rx="down")
    client.send(encode(CrtpPacket(Port.LINK, 0, b"x")))
    for step in range(1, 151):
        node.receive_crtp(node.sim.t_s)
        node.step(step)
    assert node.crtp_lost == 1 and client.receive(0.0) == []
    client.close()
    node.close()
