"""groundstation.vehicle_link: a lockstep tick's samples, truth decoded only when taken, the tlog per flush."""

from __future__ import annotations

import uuid

from groundstation.vehicle_link import VehicleLink
from link.keys import VehicleKeys
from link.mavlink.codec import ActuatorLimits, Codec
from link.mavlink.tlog import read_tlog
from link.messages import ImuSample, TruthState
from link.transports import open_transport
from model.vehicle import load_vehicle


def _truth(t: float) -> TruthState:
    return TruthState(t, (t, 0.0, 1.0), (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0))


def test_truth_waits_undecoded_until_taken_and_only_the_ticks_share(tmp_path):
    bus = f"mem:{uuid.uuid4().hex}"
    keys = VehicleKeys("t", 1)
    limits = ActuatorLimits.from_vehicle(load_vehicle())
    now = [0.5]
    link = VehicleLink(bus, keys, limits, lambda: now[0], tlog_path=tmp_path / "link.tlog")
    vehicle = Codec(system_id=1, limits=limits)
    downlink = open_transport(bus, tx=keys.downlink)
    truth = open_transport(bus, tx=keys.truth)
    try:
        for i in range(3):
            downlink.send(vehicle.encode(ImuSample(0.1 * i, (0.0, 0.0, 9.81), (0.0, 0.0, 0.0))))
            truth.send(vehicle.encode(_truth(0.1 * i)))
        link.fetch()
        assert link.raw_counts() == (3, 0, 3)
        link.deliver((2, 0, 2))  # a tick that announced two of each
        inbox = link.take()
        assert [rx.message.time_s for rx in inbox.downlink] == [0.0, 0.1]
        assert inbox.truth == [] and link.truth.stats.rx_frames == 0  # not decoded yet
        assert [rx.message.time_s for rx in link.take_truth()] == [0.0, 0.1]  # the tick's two, not the third
        assert link.take_truth() == []
        assert link.tlog.path.stat().st_size == 0  # the tick's records wait for flush_logs
        link.flush_logs()
        assert len(read_tlog(link.tlog.path)) == 2  # the downlink frames (truth never passes the radio)
        link.deliver()  # realtime: everything held, truth included when taken
        assert [rx.message.time_s for rx in link.take().downlink] == [0.2]
        assert [rx.message.time_s for rx in link.take_truth()] == [0.2]
    finally:
        for transport in (downlink, truth):
            transport.close()
        link.close()
    assert len(read_tlog(tmp_path / "link.tlog")) == 3  # close flushes the rest
