"""`cfstack step`: the lab report's tuning experiment, flown as the lab flew it, and what makes hardware differ.

Takes in: the step (axis, size, hold) and the flight options of `fly` (cfstack fly --help). The defaults are
the lab's experiment (../shared/lab-report.md, Fig. 1): attitude mode, the `lab` radio, the faithful vehicle
(--firmware crazyflie, --vehicle-model cf21, --vehicle-draw lab) and the report's gains (gains.toml).
Gives out: the flight's summary, then the step metrics, each with its definition, beside the lab's Fig. 1
values (groundstation/params/lab_fig1.toml), and a Fig. 1-like PNG in the log folder. With --json one JSON
object (the summary with "step" and "lab_fig1"). With --ablate: the same step flown once as configured and
once with each modelled cause of the hardware/simulation gap made ideal in turn (radio latency, the onboard
PID and its estimator vs the ideal law, the onboard estimator, motor lag, PWM/battery, the mass offset, the
whole vehicle draw), as
a table (stdout, and ablation.csv) and an overlay plot (ablation.png) in the log folder; --jobs flights at
once (spawned processes, each with its own emulator child), a progress line on stderr as each ends.
Exit code 0 when the flight (every flight with --ablate) reached its goal, 1 otherwise, 2 for bad input.
"""

from __future__ import annotations

import argparse
import copy
import csv
import dataclasses
import math
import multiprocessing
import os
import re
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

import numpy as np

from groundstation.cli import (
    FlightFailed,
    _emulator_arguments,
    _flight_arguments,
    _options,
    _parsed,
    _settings,
    _user_code,
    fly_with_emulator,
)
from groundstation.step_analysis import StepMetrics, analyze_step, plot_step
from groundstation.trajectories.basic import Step, load_trajectory_params
from link.transports.zenoh_session import zenoh_options_from_args
from model.config import Params, builtin_path, resolve
from model.errors import OneLineParser, UserError
from model.options import float_in, non_negative_float, whole_number

# The lab's experiment (lab report, section II): what `cfstack step` flies unless told otherwise.
LAB_EXPERIMENT = {"mode": "attitude", "radio": "lab", "firmware": "crazyflie", "vehicle_model": "cf21",
                  "vehicle_draw": "lab"}

# (metric, unit, definition) in the order printed; the definitions are the report's (step_analysis.py).
METRICS = (
    ("percent_overshoot", "%", "PO = (peak - final value) / (final value - start) x 100"),
    ("damping_ratio", "", "zeta = -ln(PO/100) / sqrt(pi^2 + ln(PO/100)^2), from the overshoot"),
    ("rise_time_s", "s", "rise time (the report's): from the step to FIRST reaching the final value"),
    ("rise_time_10_90_s", "s", "10-90 % rise time: from 10 % to 90 % of the way to the final value"),
    ("settling_time_s", "s", "settling time: from the step until the response stays in the +-5 % band"),
    ("steady_state_error_m", "m", "steady-state error: target - final value (mean of the last fifth)"),
)


@dataclasses.dataclass(frozen=True)
class Ablation:
    """One flight of the ablation: what is made ideal, and how (fly options, emulator parts)."""

    name: str
    label: str
    options: dict
    ideal_parts: tuple[str, ...] = ()
    no_motor_lag: bool = False
    no_mass_offset: bool = False


ABLATIONS = (
    Ablation("as_configured", "as configured", {}),
    Ablation("no_latency", "no radio latency or loss (radio ideal)", {"radio": "ideal"}),
    Ablation("ideal_law", "ideal onboard law on the true state (firmware ideal)", {"firmware": "ideal"}),
    Ablation("true_attitude", "onboard PID on the true attitude (no estimator)", {}, ideal_parts=("estimator",)),
    Ablation("no_motor_lag", "no motor lag", {}, no_motor_lag=True),
    Ablation("ideal_battery", "full battery, no sag (PWM exact)", {}, ideal_parts=("battery",)),
    Ablation("no_mass_offset", "the vehicle draw without its mass offset", {}, no_mass_offset=True),
    Ablation("nominal_vehicle", "nominal vehicle (no mass, CoM, motor, IMU draw)", {"vehicle_draw": "nominal"}),
)


def command(argv: list[str]) -> int:
    defaults = load_trajectory_params().step
    p = OneLineParser(prog="cfstack step", description="The lab report's tuning experiment: hover, step along one "
                      "axis, measure the response beside the lab's Fig. 1. Defaults: the lab's experiment "
                      "(--mode attitude --radio lab --firmware crazyflie --vehicle-model cf21 --vehicle-draw lab).")
    g = p.add_argument_group("step")
    g.add_argument("--axis", choices=("x", "y", "z"), default=defaults.axis)
    g.add_argument("--size", type=_step_size, default=defaults.size_m, help="step size, m (non-zero)")
    g.add_argument("--hold", type=non_negative_float, default=defaults.hold_s, help="time to hold after the step, s")
    g.add_argument("--ablate", action="store_true",
                   help="fly the step once as configured and once with each modelled cause made ideal in turn; "
                        "a table and an overlay plot of what makes hardware differ from the ideal simulation")
    g.add_argument("--jobs", type=whole_number(1, "a number of flights"), default=None,
                   help="with --ablate: flights flown at once, each with its own emulator (default: the number "
                        "of CPUs; 1 with --connect, whose one vehicle flies them in turn). Lockstep flights are "
                        "the same whatever the number")
    _flight_arguments(p)
    _emulator_arguments(p)
    p.set_defaults(**LAB_EXPERIMENT)
    args = _parsed(p, argv)
    if args.jobs is not None and not args.ablate:
        raise UserError("--jobs: only --ablate flies more than one flight")
    if args.ablate:
        return _ablate(args, defaults, _ablation_jobs(args))
    metrics, summary, png, _ = _fly_step(args, defaults)
    lab = load_lab_fig1()
    summary = summary | {"step": dataclasses.asdict(metrics), "step_plot": str(png), "lab_fig1": lab}
    from groundstation.session import dump_json, human_summary

    if args.json:
        print(dump_json(summary))
    else:
        print(human_summary(summary))
        print(step_report(metrics, png, lab, args.axis))
    return 0 if summary["reached_goal"] else 1


def _fly_step(args, defaults) -> tuple[StepMetrics, dict, Path, tuple[np.ndarray, np.ndarray]]:
    """One step flight: its metrics, summary, plot, and the (t, y) response (t from the start of tracking)."""
    start = np.array([0.0, 0.0, load_trajectory_params().hover.height_m])
    track = Step(start, args.axis, args.size, hold_s=args.hold, step_at_s=defaults.step_at_s)
    zopts = zenoh_options_from_args(args)
    settings = _settings(args, args.clock)

    def prepared():
        return _options(settings, None, track, track.end_m, {"trajectory": f"step-{args.axis}"}, None, zopts,
                        _user_code(args, None))

    result = fly_with_emulator(args, None, False, zopts, prepared)
    if "track" not in result.record.phase:
        from groundstation.session import human_summary

        print(human_summary(result.summary), file=sys.stderr)
        raise FlightFailed(f"the flight ended ({result.summary['result']}) before the step was flown")
    t, y = _response(result, args.axis)
    index = "xyz".index(args.axis)
    metrics = analyze_step(t, y, track.step_at_s, float(track.start_m[index]), float(track.end_m[index]))
    png = Path(result.summary["log_dir"]) / f"step_{args.axis}.png"
    plot_step(t, y, metrics, png, axis_name=args.axis)
    return metrics, result.summary, png, (t, y)


def _response(result, axis: str) -> tuple[np.ndarray, np.ndarray]:
    """The flown axis while tracking and hovering (truth when the link has it, else the estimate)."""
    rec = result.record
    index = "xyz".index(axis)
    track_start = next(t for t, phase in zip(rec.t, rec.phase, strict=True) if phase == "track")
    rows = [(t, truth if truth is not None else est)
            for t, phase, truth, est in zip(rec.t, rec.phase, rec.truth, rec.est, strict=True)
            if phase in ("track", "hover") and (truth is not None or est is not None)]
    return np.array([r[0] for r in rows]) - track_start, np.array([r[1][index] for r in rows])


def load_lab_fig1(name_or_path: str = "lab_fig1") -> dict:
    p = Params.load(resolve(name_or_path, "groundstation", "params", "lab step-response figures"))
    values = {key: p.number(key) for key, _, _ in METRICS if key in p.data}
    return {"axis": p.string("axis"), **values, "source": p.string("source")}


def step_report(m: StepMetrics, png: Path, lab: dict, axis: str) -> str:
    """Each metric with its definition, beside the lab's Fig. 1 (when the axis is the lab's)."""
    same_axis = lab["axis"] == axis
    lines = [f"step {m.initial_m:.3f} -> {m.target_m:.3f} m in {axis} at t = {m.step_time_s:.2f} s; "
             f"{'lab Fig. 1' if same_axis else 'lab Fig. 1 is a step in ' + lab['axis'] + ', not shown'}",
             f"{'metric':<22} {'this flight':>12} {'lab Fig. 1':>11}  definition"]
    for key, unit, definition in METRICS:
        value = getattr(m, key)
        lab_value = lab.get(key) if same_axis else None
        lines.append(f"{key:<22} {_fmt(value, unit):>12} {_fmt(lab_value, unit):>11}  {definition}")
    lines.append(f"plot: {png}")
    lines.append(f"lab figures: {lab['source']}")
    return "\n".join(lines)


def _fmt(value, unit: str) -> str:
    if value is None:
        return "-"
    if isinstance(value, float) and not math.isfinite(value):
        return "none"
    return f"{value:.3f}{(' ' + unit) if unit else ''}"


def _ablation_jobs(args) -> int:
    """Flights of --ablate flown at once: each has its own emulator child, except with --connect."""
    if zenoh_options_from_args(args).get("connect"):
        if args.jobs not in (None, 1):
            raise UserError(f"--jobs {args.jobs}: with --connect the flights share one vehicle; use --jobs 1")
        return 1
    return min(args.jobs or os.cpu_count() or 1, len(ABLATIONS))


def _ablate(args, defaults, jobs: int) -> int:
    """Every ablation flown (jobs at once); the table, ablation.csv and ablation.png in the parent log folder."""
    folder = Path(args.log) if args.log else Path("flights") / "ablation"
    folder.mkdir(parents=True, exist_ok=True)
    runs = [_ablation_args(args, ablation, folder) for ablation in ABLATIONS]
    print(f"{len(ABLATIONS)} flights, {jobs} at once; logs in {folder}", file=sys.stderr, flush=True)
    flown = _fly_ablations(runs, defaults, jobs)
    pairs = list(zip(ABLATIONS, flown, strict=True))
    rows = [(ablation, metrics, summary["result"]) for ablation, (metrics, summary, _) in pairs]
    responses = [(ablation, metrics, response) for ablation, (metrics, _, response) in pairs]
    failed = sum(not summary["reached_goal"] for _, summary, _ in flown)
    _write_table(folder / "ablation.csv", rows)
    png = _plot_overlay(folder / "ablation.png", responses, args.axis)
    print(ablation_table(rows, load_lab_fig1(), args.axis))
    print(f"table: {folder / 'ablation.csv'}\nplot: {png}")
    return 0 if failed == 0 else 1


def _fly_ablations(runs: list, defaults, jobs: int) -> list[tuple[StepMetrics, dict, tuple]]:
    """(metrics, summary, response) of each run, in order; a progress line as each flight ends. With jobs > 1
    they fly in spawned worker processes (the ground station's loop holds the GIL)."""
    flown: dict[int, tuple] = {}

    def done(i: int, result: tuple) -> None:
        flown[i] = result
        print(f"[{len(flown)}/{len(runs)}] {ABLATIONS[i].label}: {result[1]['result']}", file=sys.stderr, flush=True)

    if jobs == 1:
        for i, run in enumerate(runs):
            done(i, _fly_ablation(run, defaults))
        return [flown[i] for i in range(len(runs))]
    with ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = {pool.submit(_fly_ablation, run, defaults): i for i, run in enumerate(runs)}
        try:
            for future in as_completed(futures):
                done(futures[future], future.result())
        except BrokenProcessPool:
            raise FlightFailed("a flight's worker process died; the flights that ended are in their log "
                               "folders, the table was not written") from None
        finally:
            pool.shutdown(cancel_futures=True)
    return [flown[i] for i in range(len(runs))]


def _fly_ablation(run, defaults) -> tuple[StepMetrics, dict, tuple]:
    metrics, summary, _, response = _fly_step(run, defaults)
    return metrics, summary, response


def _ablation_args(args, ablation: Ablation, folder: Path):
    run = copy.copy(args)
    for key, value in ablation.options.items():
        setattr(run, key, value)
    run.log = str(folder / ablation.name)
    run.emulator_extra = list(args.emulator_extra) + [f"--ideal={part}" for part in ablation.ideal_parts]
    run.json = False
    if ablation.no_motor_lag:
        run.vehicle_model = str(_without_motor_lag(args.vehicle_model, folder))
    if ablation.no_mass_offset:
        run.vehicle_draw = str(_without_mass_offset(args.vehicle_draw, folder))
    return run


def _without_mass_offset(profile: str, folder: Path) -> Path:
    """A copy of the variation profile with mass_offset_kg = [0, 0]: every other draw stays the same (the
    draw takes the same random numbers whatever the ranges)."""
    if profile == "nominal":
        profile = "lab"  # nothing to remove from nominal: show the lab draw without its mass
    source = Path(profile) if profile.endswith(".toml") else builtin_path("simulator", "params/variation", profile)
    text = re.sub(r"(?m)^mass_offset_kg\s*=\s*\[[^\]]*\]", "mass_offset_kg = [0.0, 0.0]", source.read_text())
    path = folder / f"{source.stem}_no_mass_offset.toml"
    path.write_text(text)
    return path


def _without_motor_lag(vehicle_model: str, folder: Path) -> Path:
    """A copy of the vehicle file with time_constant_s = 0 (everything else as it is)."""
    source = Path(vehicle_model) if vehicle_model.endswith(".toml") else builtin_path(
        "model", "params/vehicles", vehicle_model)
    text = re.sub(r"(?m)^time_constant_s\s*=\s*[^#\n]*", "time_constant_s = 0.0 ", source.read_text())
    path = folder / f"{source.stem}_no_motor_lag.toml"
    path.write_text(text)
    return path


def ablation_table(rows, lab: dict, axis: str) -> str:
    """One line per flight: what was made ideal, the mission's result, the step metrics; then the lab's."""
    same_axis = lab["axis"] == axis
    header = f"{'flown with':<52}{'result':>14}" + "".join(f"{key:>22}" for key, _, _ in METRICS)
    lines = [header]
    for ablation, m, result in rows:
        lines.append(f"{ablation.label:<52}{result:>14}" + "".join(f"{_fmt(getattr(m, key), unit):>22}"
                                                                    for key, unit, _ in METRICS))
    if same_axis:
        lines.append(f"{'lab hardware (Fig. 1)':<52}{'':>14}" + "".join(f"{_fmt(lab.get(key), unit):>22}"
                                                                         for key, unit, _ in METRICS))
    return "\n".join(lines)


def _write_table(path: Path, rows) -> None:
    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["ablation", "label", "result", *(key for key, _, _ in METRICS)])
        for ablation, m, result in rows:
            writer.writerow([ablation.name, ablation.label, result, *(getattr(m, key) for key, _, _ in METRICS)])


def _plot_overlay(path: Path, responses, axis: str) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 5), dpi=120)
    try:
        for ablation, m, (t, y) in responses:
            ax.plot(t - m.step_time_s, y - m.initial_m, label=ablation.label,
                    linewidth=2.0 if ablation.name == "as_configured" else 1.0)
        m0 = responses[0][1]
        ax.axhline(m0.target_m - m0.initial_m, color="k", linestyle="--", linewidth=0.8, label="commanded step")
        ax.set_xlabel("time from the step (s)")
        ax.set_ylabel(f"{axis} displacement from the start (m)")
        ax.set_title(f"Step in {axis}: each modelled cause made ideal in turn")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="lower right", fontsize="small")
        fig.tight_layout()
        fig.savefig(path)
    finally:
        plt.close(fig)
    return path


def _step_size(text: str) -> float:
    value = float_in(-math.inf, math.inf)(text)
    if value == 0.0:
        raise argparse.ArgumentTypeError("must be a non-zero number of metres")
    return value
