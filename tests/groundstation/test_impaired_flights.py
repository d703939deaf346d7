"""Flights under impairment (issue 6, test 6): every lab maze completes in attitude mode with the `lab`
and `harsh` radio profiles, and with 30 % i.i.d. loss on both directions (lockstep, seeded)."""

import json
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from flight_helpers import radio_profile  # noqa: E402
from testsupport import SHARED_WORLDS, shared_world_params, shared_worlds_present  # noqa: E402

LAB_MAZES = shared_world_params("test_lab_*.json", "maze_20*.json")
PROFILES = ("lab", "harsh", "loss30")
CONCURRENT_FLIGHTS = 3

def fly(world: str, radio: str, log: Path) -> tuple[dict | None, str]:
    run = subprocess.run([sys.executable, "-m", "cfstack", "fly", str(SHARED_WORLDS / f"{world}.json"),
                          "--mode", "attitude", "--radio", radio, "--seed", "5", "--json", "--log", str(log)],
                         capture_output=True, text=True, timeout=600, stdin=subprocess.DEVNULL)
    return (json.loads(run.stdout) if run.stdout.strip() else None), run.stderr[-1500:]


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    root = tmp_path_factory.mktemp("impaired")
    radios = {"lab": "lab", "harsh": "harsh", "loss30": str(radio_profile(root, "loss30", loss=0.30))}
    cells = [(w, p) for w in (LAB_MAZES if shared_worlds_present() else []) for p in PROFILES]
    with ThreadPoolExecutor(CONCURRENT_FLIGHTS) as pool:
        futures = {c: pool.submit(fly, c[0], radios[c[1]], root / f"{c[0]}_{c[1]}") for c in cells}
        return {c: f.result() for c, f in futures.items()}


@pytest.mark.parametrize("profile", PROFILES)
@pytest.mark.parametrize("world", LAB_MAZES)
def test_lab_maze_completes_in_attitude_mode_under_impairment(flights, world, profile):
    summary, stderr = flights[(world, profile)]
    assert summary is not None, stderr
    assert summary["result"] == "reached_goal", (summary["result"], summary.get("failsafe_reason"))
    assert not summary["collided"]
