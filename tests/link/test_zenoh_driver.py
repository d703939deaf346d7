"""link.crtp.zenoh_driver: its URIs, and the lockstep gate that hands cflib exactly the packets released.
(cflib flies through it in tests/simulator/test_crtp_cflib.py and tests/groundstation/test_crazyflie_link.py.)"""

from __future__ import annotations

import threading

import pytest

pytest.importorskip("cflib", reason="cflib is in the test extra (pip install -e '.[test]')")

from link.clock import ClockTick, unpack_tick  # noqa: E402
from link.crtp import zenoh_driver  # noqa: E402
from link.transports import open_transport  # noqa: E402
from model.errors import UserError  # noqa: E402


def test_uris_name_the_prefix_and_vehicle_and_may_carry_the_endpoint():
    zenoh_driver.use_session("zenoh", {"connect": ["tcp/127.0.0.1:7447"]})
    keys, connection, options = zenoh_driver.parse_uri("zenoh://cfstack/3")
    assert (keys.prefix, keys.vehicle_id, connection, options) == ("cfstack", 3, "zenoh",
                                                                   {"connect": ["tcp/127.0.0.1:7447"]})
    keys, connection, options = zenoh_driver.parse_uri("zenoh://lab/a/12?connect=tcp/10.0.0.2:7447")
    assert (keys.crtp_uplink, connection, options) == ("lab/a/vehicle/12/crtp/uplink", "zenoh:tcp/10.0.0.2:7447",
                                                       {})
    for bad in ("zenoh://cfstack", "zenoh://cfstack/0", "zenoh://cfstack/251", "zenoh:///1", "zenoh://cf/x"):
        with pytest.raises(UserError, match="is not zenoh://PREFIX/VEHICLE"):
            zenoh_driver.parse_uri(bad)


def test_a_tick_record_counts_crtp_samples():
    tick = ClockTick(4, 8_000_000, 10, 2, 3, crtp_published=7)
    assert unpack_tick(tick.pack()) == tick


def _driver(bus: str) -> tuple[zenoh_driver.ZenohDriver, object]:
    zenoh_driver.use_session(f"mem:{bus}", {})
    emulator_side = open_transport(f"mem:{bus}", tx="cfstack/vehicle/1/crtp/downlink",
                                   rx="cfstack/vehicle/1/crtp/uplink")
    driver = zenoh_driver.ZenohDriver()
    answer = threading.Thread(target=lambda: [emulator_side.send(b"\xff") for _ in emulator_side.receive(2.0)])
    answer.start()  # the probe's answer
    driver.connect("zenoh://cfstack/1", None, None)
    answer.join()
    return driver, emulator_side


def test_gated_cflib_gets_exactly_the_released_packets_and_the_gate_knows_when_it_is_done():
    driver, emulator_side = _driver("zdrv-gate")
    handled: list[bytes] = []
    stop = threading.Event()

    def cflib_reader():  # what cflib's IncomingPacketHandler does
        while not stop.is_set():
            packet = driver.receive_packet(0.05)
            if packet is not None:
                handled.append(bytes((packet.header,)) + bytes(packet.data))

    reader = threading.Thread(target=cflib_reader)
    reader.start()
    driver.gate(2.0)
    assert handled == [b"\xff"]  # the probe's answer, taken before the gate, went to cflib at once
    for i in range(5):
        emulator_side.send(bytes((0x5E, i)))
    fetched = []
    while len(fetched) < 5:
        fetched += driver.fetch(0.5)
    assert driver.stats.chunks_received == 6 and handled == [b"\xff"]  # held: nothing released yet
    driver.release(2)
    driver.wait_handled(2.0)
    assert handled[1:] == [bytes((0x5E, 0)), bytes((0x5E, 1))]  # exactly two, handled when wait returns
    driver.release(3)
    driver.wait_handled(2.0)
    assert handled[1:] == [bytes((0x5E, i)) for i in range(5)]
    stop.set()
    reader.join()
    driver.close()
    emulator_side.close()


def test_a_gate_whose_packets_cflib_never_takes_is_one_line_not_a_hang():
    driver, emulator_side = _driver("zdrv-stall")
    with pytest.raises(UserError, match="cflib did not take its packets"):
        driver.gate(0.2)  # nobody reads: the probe's answer, released by the gate, is never handled
    driver.close()
    emulator_side.close()
