"""The transport contract (link/transports/base.py), run once on every scheme, plus per-scheme details.

A "pair" is two opened transports wired to each other: mem (one bus), udp (udpin <- udpout on a
free loopback port), serial (two ptys joined by a null-modem bridge) and zenoh (two peer sessions,
one listening on a free loopback port, the other connecting to it).
"""

from __future__ import annotations

import contextlib
import random
import struct
import time
from dataclasses import dataclass

import pytest

from link.transports import Transport, TransportStats, open_transport
from link.transports.table import check_radio_link, far_end, for_vehicle
from link.transports.zenoh_session import ZenohSettings, shared_session
from model.errors import UserError

SCHEMES = ["mem", "udp", "serial", "zenoh"]
# Nominal for a pty (it moves bytes as fast as they are read), real for a USB UART.
PTY_BAUD = 921600
MAVLINK2_MAX_FRAME_BYTES = 280
MAVLINK2_MIN_FRAME_BYTES = 12


@dataclass
class Pair:
    scheme: str
    a: Transport
    b: Transport
    stream: bool  # byte stream (chunks cut anywhere) rather than whole frames


def random_frames(sizes, seed: int) -> list[bytes]:
    rng = random.Random(seed)
    return [rng.randbytes(size) for size in sizes]


def numbered_frames(count: int, seed: int) -> list[bytes]:
    """Frames of MAVLink 2 sizes starting with their index, so a loss or a swap is visible."""
    rng = random.Random(seed)
    sizes = [rng.randint(MAVLINK2_MIN_FRAME_BYTES, MAVLINK2_MAX_FRAME_BYTES) for _ in range(count)]
    return [struct.pack("<I", index) + rng.randbytes(size - 4) for index, size in enumerate(sizes)]


def assert_delivered(pair: Pair, sent: list[bytes], chunks: list[bytes]) -> None:
    if pair.stream:
        assert b"".join(chunks) == b"".join(sent)
    else:
        assert len(chunks) == len(sent)
        assert chunks == sent  # each frame whole, in order


@pytest.fixture(scope="module")
def zenoh_peer_options(free_tcp_port):
    """Session options of the two zenoh ends; the sessions stay open for the whole module (the
    transports of each test share them), so each test pays for declarations, not for connecting."""
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    listener = {"address": "", "listen": [endpoint]}
    connector = {"address": endpoint, "listen": []}
    with contextlib.ExitStack() as stack:
        for options in (listener, connector):
            address = options["address"]
            settings = ZenohSettings.from_options(address, listen=options["listen"])
            stack.enter_context(shared_session(settings))
        yield listener, connector


def _open_mem(request, stack):
    name = f"contract-{request.node.name}"
    a = open_transport(f"mem:{name}", tx="ab", rx="ba")
    b = open_transport(f"mem:{name}", tx="ba", rx="ab")
    return a, b, False


def _open_udp(request, stack):
    a = open_transport("udpin:127.0.0.1:0")
    stack.callback(a.close)
    b = open_transport(f"udpout:127.0.0.1:{a.local_address[1]}")
    stack.callback(b.close)
    # udpin learns its peer from the first datagram it receives, as with MAVProxy.
    assert b.send(b"hello") and a.receive(2.0) == [b"hello"]
    assert a.send(b"hello") and b.receive(2.0) == [b"hello"]
    return a, b, False


def _open_serial(request, stack):
    device_a, device_b = request.getfixturevalue("null_modem")
    a = open_transport(f"serial:{device_a}:{PTY_BAUD}")
    stack.callback(a.close)
    b = open_transport(f"serial:{device_b}:{PTY_BAUD}")
    return a, b, True


def _open_zenoh(request, stack):
    listener, connector = request.getfixturevalue("zenoh_peer_options")
    keys = f"test/contract/{request.node.name.replace('[', '-').replace(']', '')}"
    a = open_transport(f"zenoh:{listener['address']}", tx=f"{keys}/ab", rx=f"{keys}/ba",
                       listen=listener["listen"])
    stack.callback(a.close)
    b = open_transport(f"zenoh:{connector['address']}", tx=f"{keys}/ba", rx=f"{keys}/ab",
                       listen=connector["listen"])
    stack.callback(b.close)
    # zenoh keeps no history: wait until each end's subscriber is known to the other end.
    assert a.wait_for_subscribers(5.0) and b.wait_for_subscribers(5.0)
    return a, b, False


OPENERS = {"mem": _open_mem, "udp": _open_udp, "serial": _open_serial, "zenoh": _open_zenoh}


@pytest.fixture(params=SCHEMES)
def pair(request):
    with contextlib.ExitStack() as stack:
        a, b, stream = OPENERS[request.param](request, stack)
        stack.callback(a.close)
        stack.callback(b.close)
        a.stats, b.stats = TransportStats(), TransportStats()  # forget the set-up traffic
        yield Pair(request.param, a, b, stream)


# ------------------------------------------------------------------------------------------------
# The contract, once for every scheme.


def test_open_and_close_are_idempotent(pair, transfer):
    for transport in (pair.a, pair.b):
        transport.open()  # already open: nothing happens
        assert transport.is_open
    assert_delivered(pair, [b"still works"], transfer(pair.a, pair.b, [b"still works"]))
    for transport in (pair.a, pair.b):
        transport.close()
        transport.close()
        assert not transport.is_open


def test_context_manager_closes_on_exit(pair):
    with pair.a as transport:
        assert transport is pair.a and transport.is_open
    assert not pair.a.is_open


def test_frames_of_every_mavlink_size_arrive_intact_both_ways(pair, transfer):
    sizes = range(1, MAVLINK2_MAX_FRAME_BYTES + 1)
    forth = random_frames(sizes, seed=1)
    assert_delivered(pair, forth, transfer(pair.a, pair.b, forth))
    back = random_frames(reversed(sizes), seed=2)
    assert_delivered(pair, back, transfer(pair.b, pair.a, back))


def test_receive_with_nothing_arriving_returns_empty_after_the_timeout(pair):
    started = time.monotonic()
    assert pair.b.receive(0.0) == []
    assert time.monotonic() - started < 0.1
    started = time.monotonic()
    assert pair.b.receive(0.2) == []
    waited = time.monotonic() - started
    assert 0.18 <= waited < 1.0  # roughly the timeout (upper bound generous for a busy machine)


def test_closed_transport_receives_nothing_and_refuses_to_send(pair, transfer):
    assert_delivered(pair, [b"before close"], transfer(pair.a, pair.b, [b"before close"]))
    pair.a.send(b"in flight")
    pair.b.close()
    started = time.monotonic()
    assert pair.b.receive(0.5) == []
    assert time.monotonic() - started < 0.25  # a closed transport does not wait
    pair.a.close()
    assert pair.a.send(b"after close") is False
    assert pair.a.stats.send_errors == 1


def test_stats_count_frames_and_bytes(pair, transfer):
    frames = random_frames([1, 17, 100, 280, 42], seed=3)
    total_bytes = sum(len(frame) for frame in frames)
    chunks = transfer(pair.a, pair.b, frames)
    assert_delivered(pair, frames, chunks)
    assert (pair.a.stats.frames_sent, pair.a.stats.bytes_sent) == (len(frames), total_bytes)
    assert pair.b.stats.bytes_received == total_bytes
    assert pair.b.stats.chunks_received == len(chunks)
    if not pair.stream:
        assert pair.b.stats.chunks_received == len(frames)
    assert pair.a.stats.send_errors == 0
    assert pair.b.stats.frames_sent == 0 and pair.a.stats.bytes_received == 0


def test_burst_of_2000_frames_arrives_completely(pair, transfer):
    frames = numbered_frames(2000, seed=4)
    assert_delivered(pair, frames, transfer(pair.a, pair.b, frames, timeout_s=15.0))


# ------------------------------------------------------------------------------------------------
# Connection strings a user can get wrong.


@pytest.mark.parametrize("connection, named", [
    ("udpin:nohost", "nohost"),
    ("udpout:127.0.0.1", "127.0.0.1"),
    ("udpin:127.0.0.1:99999", "99999"),
    ("udpout:127.0.0.1:fast", "fast"),
    ("udpout:no-such-host.invalid:14550", "no-such-host.invalid"),
    ("serial:/dev/x", "/dev/x"),
    ("serial:/dev/x:fast", "fast"),
    ("serial:/dev/ttyUSB0:0", "0"),
    ("serial:/dev/no-such-device:57600", "/dev/no-such-device"),
    ("zenoh:nonsense", "nonsense"),
    ("zenoh:tcp/127.0.0.1:7447,bogus", "bogus"),
    ("carrier-pigeon:coop", "carrier-pigeon"),
    ("nocolon", "nocolon"),
    ("mem:", "mem"),
])
def test_bad_connection_string_is_a_one_line_user_error(connection, named):
    with pytest.raises(UserError) as caught:
        open_transport(connection, tx="a", rx="b").close()
    message = str(caught.value)
    assert "\n" not in message and named in message


@pytest.mark.parametrize("connection, options", [
    ("mem:x", {"colour": "red"}),
    ("udpin:127.0.0.1:0", {"baud": 57600}),
    ("zenoh", {"mode": "satellite"}),
    ("zenoh", {"mode": "client"}),  # a client with nothing to connect to
    ("zenoh", {"config_file": "/no/such/zenoh.json5"}),
])
def test_bad_option_is_a_one_line_user_error(connection, options):
    with pytest.raises(UserError) as caught:
        open_transport(connection, tx="a", rx="b", **options).close()
    assert "\n" not in str(caught.value)


def test_bad_zenoh_key_is_a_one_line_user_error():
    with pytest.raises(UserError, match="a//b") as caught:
        open_transport("zenoh", tx="a//b")
    assert "\n" not in str(caught.value)


# ------------------------------------------------------------------------------------------------
# mem: a bus shared by name; never hears itself; bounded queues drop and count.


def test_mem_delivers_to_everyone_else_on_the_bus_but_not_the_sender():
    with (open_transport("mem:party") as alice, open_transport("mem:party") as bob,
          open_transport("mem:party") as carol, open_transport("mem:other") as stranger):
        alice.send(b"hi all")
        assert bob.receive(1.0) == [b"hi all"] and carol.receive(1.0) == [b"hi all"]
        assert alice.receive(0.05) == [] and stranger.receive(0.05) == []


def test_mem_channels_route_by_name():
    with (open_transport("mem:ch", tx="up", rx="down") as ground,
          open_transport("mem:ch", tx="down", rx="up") as vehicle,
          open_transport("mem:ch", tx="telemetry", rx="telemetry") as bystander):
        ground.send(b"command")
        vehicle.send(b"reply")
        assert vehicle.receive(1.0) == [b"command"] and ground.receive(1.0) == [b"reply"]
        assert bystander.receive(0.05) == []


def test_mem_full_queue_drops_the_excess_and_counts_it():
    with open_transport("mem:small", queue_frames=4) as reader, open_transport("mem:small") as writer:
        frames = [bytes([index]) for index in range(10)]
        for frame in frames:
            assert writer.send(frame)  # the sender is never blocked by a slow reader
        assert reader.receive(0.1) == frames[:4]
        assert reader.frames_dropped == 6


# ------------------------------------------------------------------------------------------------
# udp: MAVProxy / QGroundControl semantics.


def test_udpin_replies_to_the_last_peer_that_spoke():
    with open_transport("udpin:127.0.0.1:0") as server:
        port = server.local_address[1]
        assert server.send(b"nobody yet") is False and server.stats.send_errors == 1
        with open_transport(f"udpout:127.0.0.1:{port}") as first, \
                open_transport(f"udpout:127.0.0.1:{port}") as second:
            first.send(b"from first")
            assert server.receive(1.0) == [b"from first"]
            server.send(b"to first")
            assert first.receive(1.0) == [b"to first"]
            second.send(b"from second")
            assert server.receive(1.0) == [b"from second"]
            server.send(b"to second")
            assert second.receive(1.0) == [b"to second"] and first.receive(0.05) == []


def _heartbeat_frame(mavlink, system_id: int) -> bytes:
    mav = mavlink.MAVLink(None, srcSystem=system_id, srcComponent=1)
    return mav.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_GENERIC, 0, 0, 0).pack(mav)


def _send_gcs_heartbeat(tool) -> None:
    mavlink = tool.mav
    mavlink.heartbeat_send(6, 8, 0, 0, 0)  # MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID


def _source_system(mavlink, frame: bytes) -> int:
    message = mavlink.MAVLink(None).parse_char(frame)
    assert message is not None and message.get_type() == "HEARTBEAT"
    return message.get_srcSystem()


def test_pymavlink_udpout_talks_to_our_udpin(free_udp_port):
    from pymavlink import mavutil

    port = free_udp_port()
    with open_transport(f"udpin:127.0.0.1:{port}") as ours:
        tool = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255)
        try:
            _send_gcs_heartbeat(tool)
            (frame,) = ours.receive(2.0)
            assert _source_system(mavutil.mavlink, frame) == 255  # one whole frame from the tool
            assert ours.send(_heartbeat_frame(mavutil.mavlink, system_id=7))
            reply = tool.recv_match(type="HEARTBEAT", blocking=True, timeout=2.0)
            assert reply is not None and reply.get_srcSystem() == 7
        finally:
            tool.close()


def test_our_udpout_talks_to_pymavlink_udpin(free_udp_port):
    from pymavlink import mavutil

    port = free_udp_port()
    tool = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255)
    try:
        with open_transport(f"udpout:127.0.0.1:{port}") as ours:
            assert ours.send(_heartbeat_frame(mavutil.mavlink, system_id=9))
            heard = tool.recv_match(type="HEARTBEAT", blocking=True, timeout=2.0)
            assert heard is not None and heard.get_srcSystem() == 9
            _send_gcs_heartbeat(tool)
            (frame,) = ours.receive(2.0)
            assert _source_system(mavutil.mavlink, frame) == 255
    finally:
        tool.close()


# --- one vehicle's link from a fleet's connection string (link.transports.table) --------------------------
@pytest.mark.parametrize(("connection", "vehicle", "expected"), [
    ("zenoh", 7, "zenoh"),  # keyed: the keys tell vehicles apart
    ("mem:bus", 3, "mem:bus"),
    ("udpin:127.0.0.1:14560", 1, "udpin:127.0.0.1:14560"),
    ("udpin:127.0.0.1:14560", 4, "udpin:127.0.0.1:14563"),  # CrazySim / PX4 SITL: PORT+N-1
    ("udpout:[::1]:14560", 2, "udpout:[::1]:14561"),
    ("serial:/dev/ttyUSB0:57600", 1, "serial:/dev/ttyUSB0:57600"),
])
def test_each_vehicle_gets_its_own_address_on_a_point_to_point_link(connection, vehicle, expected):
    assert for_vehicle(connection, vehicle) == expected


@pytest.mark.parametrize(("connection", "vehicles", "clock", "named"), [
    ("serial:/dev/ttyUSB0:57600", 2, "realtime", "carries one vehicle"),
    ("udpin:127.0.0.1:65535", 2, "realtime", "no UDP port left"),
    ("serial:/dev/ttyUSB0:57600", 1, "lockstep", "--clock realtime"),
    ("tcp:127.0.0.1:5760", 1, "realtime", "unknown transport scheme 'tcp'"),
])
def test_a_radio_link_no_emulator_can_run_on_is_one_line(connection, vehicles, clock, named):
    with pytest.raises(UserError, match=named) as err:
        check_radio_link(connection, vehicles, clock)
    assert "\n" not in str(err.value)


def test_the_far_end_swaps_udpin_and_udpout_and_has_none_for_a_device():
    assert far_end("udpin:127.0.0.1:14560") == "udpout:127.0.0.1:14560"
    assert far_end("udpout:127.0.0.1:14560") == "udpin:127.0.0.1:14560"
    assert far_end("zenoh") == "zenoh"
    with pytest.raises(UserError, match="another device"):
        far_end("serial:/dev/ttyUSB0:57600")
