"""Flights under impairment (issue 6, test 6): every lab maze completes in attitude mode with the `lab`
and `harsh` radio profiles, and with 30 % i.i.d. loss on both directions (lockstep, seeded).

The flights fly in long-lived workers that import the ground station once (tests/flight_batch.py); the last
one, flown by a worker that has flown others before it, is checked against the same command line run as a
fresh `cfstack fly` process: the same states.csv and the same MAVLink frames, byte for byte.
"""

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from flight_batch import fly_batch  # noqa: E402
from flight_helpers import radio_profile  # noqa: E402
from testsupport import SHARED_WORLDS, cfstack, shared_world_params, shared_worlds_present  # noqa: E402

from link.mavlink.tlog import read_tlog  # noqa: E402

LAB_MAZES = shared_world_params("test_lab_*.json", "maze_20*.json")
PROFILES = ("lab", "harsh", "loss30")
CONCURRENT_FLIGHTS = 3

def fly_words(world: str, radio: str, log: Path) -> list[str]:
    """The `cfstack fly` command line of one cell (the words after `cfstack fly`)."""
    return [str(SHARED_WORLDS / f"{world}.json"), "--mode", "attitude", "--radio", radio, "--seed", "5", "--json",
            "--log", str(log)]


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    """Per cell: (command line, exit code, summary, stderr tail)."""
    root = tmp_path_factory.mktemp("impaired")
    radios = {"lab": "lab", "harsh": "harsh", "loss30": str(radio_profile(root, "loss30", loss=0.30))}
    cells = [(w, p) for w in (LAB_MAZES if shared_worlds_present() else []) for p in PROFILES]
    words = {c: fly_words(c[0], radios[c[1]], root / f"{c[0]}_{c[1]}") for c in cells}
    flown = fly_batch(words, CONCURRENT_FLIGHTS)
    return {c: (words[c], *flown[c]) for c in cells}


@pytest.mark.parametrize("profile", PROFILES)
@pytest.mark.parametrize("world", LAB_MAZES)
def test_lab_maze_completes_in_attitude_mode_under_impairment(flights, world, profile):
    _, code, summary, stderr = flights[(world, profile)]
    assert summary is not None, stderr
    assert code == 0, stderr
    assert summary["result"] == "reached_goal", (summary["result"], summary.get("failsafe_reason"))
    assert not summary["collided"]


def test_the_last_batch_flight_is_the_commands_flight_byte_for_byte(flights, tmp_path):
    if not flights:
        pytest.skip("no lab mazes to fly (see the other tests' skip reason)")
    words, code, summary, stderr = flights[list(flights)[-1]]
    assert code == 0, stderr
    batch_log = Path(summary["log_dir"])
    log = tmp_path / "command"
    run = cfstack("fly", *words[:words.index("--log")], "--log", str(log), timeout=600)
    assert run.returncode == 0, run.stderr[-1500:]
    assert (log / "states.csv").read_bytes() == (batch_log / "states.csv").read_bytes()
    frames = [[record.frame for _, record in read_tlog(folder / "link.mavlink.tlog")] for folder in (log, batch_log)]
    assert len(frames[0]) > 1000 and frames[0] == frames[1]
