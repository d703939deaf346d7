"""When `cfstack fly` starts its emulator child: in lockstep before the user's code and the planning (the
child's time stands still until the ground station joins, so its start-up overlaps ours); in realtime after
them (the vehicle lives from the child's start: an airborne start levels after 0.5 s without setpoints and
stops its motors at 2 s, so a slow student trajectory must not run while it waits)."""

from __future__ import annotations

import pytest

import groundstation.session
from groundstation import cli


class RecordingChild:
    """Stands in for the emulator process: records when it is started and stopped."""

    def __init__(self, events: list[str]):
        events.append("child started")
        self.events = events
        self.endpoint = "tcp/127.0.0.1:1"
        self.crtp_port = None

    def check_started(self) -> None:
        pass

    def failure(self) -> None:
        return None

    def stop(self) -> list[str]:
        self.events.append("child stopped")
        return []


@pytest.fixture
def events(monkeypatch) -> list[str]:
    events: list[str] = []
    user_code = cli._user_code

    def recorded_user_code(*args, **kwargs):
        events.append("user code and planning")
        return user_code(*args, **kwargs)

    def recorded_session(opts):
        events.append(f"session on {opts.zenoh_options['connect'][0]}")
        return "flown"

    monkeypatch.setattr(cli, "EmulatorChild", lambda *args: RecordingChild(events))
    monkeypatch.setattr(cli, "_user_code", recorded_user_code)
    monkeypatch.setattr(groundstation.session, "run_session", recorded_session)
    return events


@pytest.mark.parametrize(("clock", "order"), [
    ("lockstep", ["child started", "user code and planning", "session on tcp/127.0.0.1:1", "child stopped"]),
    ("realtime", ["user code and planning", "child started", "session on tcp/127.0.0.1:1", "child stopped"]),
])
def test_the_child_starts_before_the_preparations_only_when_its_time_stands_still(events, clock, order):
    args = cli._parsed(cli.fly_parser(), ["--trajectory", "hover", "--clock", clock])
    assert cli.fly(args) == "flown"
    assert events == order
