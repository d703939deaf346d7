"""`cfstack step`: by default the lab's experiment (attitude mode, lab radio, the faithful vehicle), reported
beside the lab's Fig. 1 with each metric's definition; `--ablate` flies each modelled cause made ideal."""

import csv
import json
import os
import re
from concurrent.futures import ThreadPoolExecutor

import pytest
from testsupport import SHARED_WORLDS, cfstack

from groundstation.step_cli import ABLATIONS, LAB_EXPERIMENT, METRICS, load_lab_fig1

LAB_REPORT = SHARED_WORLDS.parent / "lab-report.md"


def test_the_lab_figures_are_the_reports():
    if not LAB_REPORT.is_file():
        pytest.skip(f"{LAB_REPORT} is absent (the shared material sits beside the checkout)")
    text = LAB_REPORT.read_text()
    lab = load_lab_fig1()
    assert "step-y response" in text and lab["axis"] == "y"
    assert re.search(r"steady state error is found as 0\.045", text) and lab["steady_state_error_m"] == 0.045
    assert "= 32\\%" in text and lab["percent_overshoot"] == 32.0
    assert "settling time is found as 3s" in text and lab["settling_time_s"] == 3.0
    assert "rise time as 0.45s" in text and lab["rise_time_s"] == 0.45
    assert "0.3409598" in text and lab["damping_ratio"] == pytest.approx(0.3409598, abs=1e-3)


def test_the_default_step_is_the_labs_experiment_reported_beside_fig1(tmp_path):
    with ThreadPoolExecutor(2) as pool:  # the JSON and the human report at once: two independent lockstep flights
        words = ("step", "--axis", "y", "--size", "0.5")
        as_json = pool.submit(cfstack, *words, "--json", "--log", str(tmp_path / "log"))
        as_text = pool.submit(cfstack, *words, "--log", str(tmp_path / "again"))
        run, human = as_json.result(), as_text.result().stdout
    assert run.returncode in (0, 1), run.stderr
    summary = json.loads(run.stdout)
    assert summary["mode"] == "attitude" and summary["firmware"] == "crazyflie"
    assert summary["vehicle_draw"] == "lab" and LAB_EXPERIMENT["radio"] == "lab"
    assert summary["link"]["rtt_ms_p50"] >= 40.0  # the lab radio profile's latency, not the default's
    step = summary["step"]
    assert step["target_m"] - step["initial_m"] == pytest.approx(0.5)
    assert summary["lab_fig1"]["percent_overshoot"] == 32.0
    for key, _, definition in METRICS:
        assert re.search(rf"^{key}\s+\S+.*{re.escape(definition)}$", human, re.M), key
    assert "rise_time_s" in human and "rise_time_10_90_s" in human


def test_ablation_flies_each_cause_made_ideal_and_tabulates_them(tmp_path):
    folder = tmp_path / "ablation"
    run = cfstack("step", "--axis", "y", "--size", "0.5", "--ablate", "--log", str(folder), timeout=600)
    assert run.returncode in (0, 1), run.stderr
    with (folder / "ablation.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [r["ablation"] for r in rows] == [a.name for a in ABLATIONS]
    flown = {a.name: json.loads((folder / a.name / "summary.json").read_text()) for a in ABLATIONS}
    # each flight changed exactly what its row says
    assert flown["as_configured"]["firmware"] == "crazyflie" and flown["as_configured"]["vehicle_draw"] == "lab"
    assert flown["no_latency"]["link"]["rtt_ms_p50"] < flown["as_configured"]["link"]["rtt_ms_p50"]
    assert flown["ideal_law"]["firmware"] == "ideal"
    assert flown["nominal_vehicle"]["vehicle_draw"] == "nominal"
    assert "mass_offset_kg = [0.0, 0.0]" in (folder / "lab_no_mass_offset.toml").read_text()
    assert (folder / "cf21_no_motor_lag.toml").read_text().count("time_constant_s = 0.0") == 1
    assert (folder / "ablation.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "lab hardware (Fig. 1)" in run.stdout
    # the default flies as many at once as there are CPUs (each lockstep flight is the same whatever the
    # number: `--jobs 1` gave byte-identical states.csv and ablation.csv by hand, see the README)
    assert f"{len(ABLATIONS)} flights, {min(os.cpu_count() or 1, len(ABLATIONS))} at once" in run.stderr
    assert sorted(re.findall(r"^\[(\d)/8\] ", run.stderr, re.M)) == [str(i) for i in range(1, 9)]


@pytest.mark.parametrize("argv, fragment", [
    (("--jobs", "2"), "only --ablate"),
    (("--ablate", "--jobs", "2", "--connect", "tcp/127.0.0.1:9"), "share one vehicle"),
])
def test_jobs_is_refused_where_it_cannot_mean_flights_at_once(argv, fragment):
    run = cfstack("step", *argv, timeout=30)
    assert run.returncode == 2 and run.stdout == ""
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("cfstack step: --jobs") and fragment in lines[0]
