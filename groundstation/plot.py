"""`cfstack plot LOGDIR`: figures of one flight from its log folder.

Takes in: a flight log folder (states.csv, optional summary.json and plan.json; see logread.py) and
optionally `--out DIR` for the figures (default: the log folder).
Gives out: PNG files (position, velocity, tracking_error, estimator_error when there is ground truth,
commands, link_health; trajectory_3d and position_velocity when the flight was planned through a
world), the list of files written on stdout, notes for anything skipped; a one-line UserError for a
missing or malformed log.

Rendering uses matplotlib's Agg canvas directly (no pyplot, no display, no global figure state).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

import numpy as np
from matplotlib import colors as mcolors
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle
from mpl_toolkits.mplot3d.art3d import Poly3DCollection

from groundstation.logread import FlightLog, read_log
from model.errors import UserError, WorldError
from model.frames import roll_pitch_yaw_deg
from model.world import World, load_world

AXES = "xyz"
AXIS_COLORS = ("tab:red", "tab:green", "tab:blue")  # x, y, z: the usual RGB axis convention
SOURCE_STYLE = {  # how each signal is drawn in every time plot, so they read the same everywhere
    "ref": dict(label="reference", color="black", linestyle="--", linewidth=1.2),
    "est": dict(label="estimate", color="tab:blue", linewidth=1.0),
    "truth": dict(label="truth", color="tab:orange", linewidth=1.0, alpha=0.85),
}
PHASE_COLORS = {
    "connect": "#d9d9d9", "arm": "#bdbdbd", "takeoff": "#c6dbef", "settle": "#c7e9c0", "track": "#fdd0a2",
    "hover": "#dadaeb", "land": "#9ecae1", "disarm": "#bdbdbd", "done": "#f0f0f0",
    "failsafe_hold": "#fc9272", "failsafe_descent": "#ef3b2c",
}
UNKNOWN_BLOCK_COLOR = "grey"
BLOCK_ALPHA = 0.25
DEFAULT_RATE_WINDOW_S = 1.0  # counter differencing window: long enough to average the per-tick 0/1 steps
FIG_DPI = 110
SATURATED_LABEL = "saturated tick (cmd_saturated = 1)"
SIGMA_BAND = 3.0  # estimator error plotted against +-3 sigma: ~99.7 % of a consistent Gaussian error


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cfstack plot", description=__doc__.splitlines()[0])
    p.add_argument("logdir", help="flight log folder written by `cfstack fly --log DIR`")
    p.add_argument("--out", metavar="DIR", help="folder for the PNG files (default: LOGDIR)")
    p.add_argument("--rate-window", type=float, default=DEFAULT_RATE_WINDOW_S, metavar="S",
                   help="window (s) for message rates from the cumulative counters "
                        f"(default {DEFAULT_RATE_WINDOW_S})")
    return p


def command(argv: list[str]) -> int:
    """Entry point of `cfstack plot`; returns the exit code (0), raises UserError on bad input."""
    args = build_parser().parse_args(argv)
    if not args.rate_window > 0:
        raise UserError(f"--rate-window {args.rate_window}: must be > 0 s")
    log = read_log(args.logdir)
    out = Path(args.out) if args.out else log.folder
    if out.exists() and not out.is_dir():
        raise UserError(f"--out {out}: exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    written, notes = plot_log(log, out, rate_window_s=args.rate_window)
    for path in written:
        print(path)
    for note in (*log.warnings, *notes):
        print(f"note: {note}")
    return 0


def plot_log(log: FlightLog, out: Path,
             rate_window_s: float = DEFAULT_RATE_WINDOW_S) -> tuple[list[Path], list[str]]:
    """Write every figure the log supports into `out`; returns (files written, notes on what was skipped)."""
    written: list[Path] = []
    notes: list[str] = []
    plots: list[tuple[str, Callable[[FlightLog], Figure]]] = [
        ("position.png", lambda lg: plot_states(lg, "position")),
        ("velocity.png", lambda lg: plot_states(lg, "velocity")),
        ("tracking_error.png", plot_tracking_error),
    ]
    if log.has_truth:
        plots.append(("estimator_error.png", plot_estimator_error))
    else:
        notes.append("estimator_error.png skipped: no ground truth (truth_* columns empty: a real vehicle)")
    plots += [("commands.png", plot_commands),
              ("link_health.png", lambda lg: plot_link_health(lg, rate_window_s))]
    if log.plan is not None:
        world, world_note = _load_plan_world(log)
        if world_note:
            notes.append(world_note)
        plots += [("trajectory_3d.png", lambda lg: plot_trajectory_3d(lg, world)),
                  ("trajectory_top.png", lambda lg: plot_trajectory_top(lg, world)),
                  ("position_velocity.png", plot_position_velocity)]
    for name, make in plots:
        written.append(_save(make(log), out / name))
    return written, notes


# ---------------------------------------------------------------- time plots


def plot_states(log: FlightLog, quantity: str) -> Figure:
    """Three stacked panels (x, y, z) of position or velocity: reference, estimate, truth (if present)."""
    unit = "m" if quantity == "position" else "m/s"
    fig, axes = _figure(3, sharex=True)
    for source in ("ref", "est", "truth"):
        values = log.position_m(source) if quantity == "position" else log.velocity_mps(source)
        for i, ax in enumerate(axes):
            if np.isfinite(values[:, i]).any():
                ax.plot(log.t_s, values[:, i], **SOURCE_STYLE[source])
    _mark_phases(axes, log)
    symbol = "" if quantity == "position" else "v"
    for i, ax in enumerate(axes):
        ax.set_ylabel(f"{symbol}{AXES[i]} ({unit})")
        ax.grid(alpha=0.3)
    _legend(axes[0])
    axes[-1].set_xlabel("time t (s)")
    fig.suptitle(f"{quantity.capitalize()} (world ENU): {_flight_name(log)}")
    return fig


def plot_tracking_error(log: FlightLog) -> Figure:
    """|p - p_ref| (m) against time, p = truth (else estimate); RMS in the legend; phases shaded."""
    source = "truth" if log.has_truth else "est"
    error = np.linalg.norm(log.position_m(source) - log.position_m("ref"), axis=1)
    fig, (ax,) = _figure(1)
    _shade_phases(ax, log)
    label = f"|{SOURCE_STYLE[source]['label']} - reference|, RMS {_rms(error):.3f} m"
    in_track = log.phase == "track"
    if in_track.any() and np.isfinite(error[in_track]).any():
        label += f" (track phase {_rms(error[in_track]):.3f} m)"
    ax.plot(log.t_s, error, color="black", linewidth=1.0, label=label)
    ax.set_xlabel("time t (s)")
    ax.set_ylabel("position error (m)")
    ax.set_ylim(bottom=0.0)
    ax.grid(alpha=0.3)
    handles, labels = ax.get_legend_handles_labels()
    # below the axes: the phase spans fill the whole plot, so any legend inside would hide the error
    fig.legend(handles, labels, loc="outside lower center", fontsize="small", ncols=4)
    ax.set_title(f"Tracking error ({SOURCE_STYLE[source]['label']} vs reference): {_flight_name(log)}")
    return fig


def _robust_limits(ax, error: np.ndarray, sigma: np.ndarray) -> None:
    """Scale the panel to the bulk of the error and its 3 sigma band (99.5th percentile of each), so that one
    touchdown spike does not flatten the flight; what falls outside is said in the panel."""
    known = np.abs(error[np.isfinite(error)])
    band = sigma[np.isfinite(sigma)]
    if not known.size:
        return
    limit = 1.2 * max(np.percentile(known, 99.5), np.percentile(band, 99.5) if band.size else 0.0)
    if limit <= 0.0 or known.max() <= limit:
        return
    ax.set_ylim(-limit, limit)
    outside = int(np.count_nonzero(known > limit))
    ax.text(0.01, 0.05, f"{outside} sample(s) beyond the scale (max {known.max():.3g})", transform=ax.transAxes,
            fontsize="x-small", color="0.35")


def _truth_at_estimate_time(log: FlightLog, truth: np.ndarray) -> np.ndarray:
    """The truth at each row's estimate sample time (interpolated between the truth samples by their own
    times): a row's truth and estimate were sampled a few ms apart, which at 1 m/s is a millimetre, larger
    than the estimator's sigma. Logs without the time columns keep the row's truth."""
    t_est, t_truth = log.columns["est_time_s"], log.columns["truth_time_s"]
    known = np.isfinite(t_truth) & np.isfinite(truth).all(axis=1)
    if not known.any() or not np.isfinite(t_est).any():
        return truth
    order = np.argsort(t_truth[known], kind="stable")
    times = t_truth[known][order]
    aligned = np.column_stack([np.interp(t_est, times, truth[known][order][:, i], left=np.nan, right=np.nan)
                               for i in range(3)])
    return np.where(np.isfinite(t_est)[:, None], aligned, np.nan)


def plot_estimator_error(log: FlightLog) -> Figure:
    """Estimate - truth per axis for position (left) and velocity (right) with +-3 sigma bands."""
    fig, grid = _figure(3, ncols=2, sharex=True)
    for col, (quantity, unit, sigma_fmt) in enumerate((("position", "m", "est_sigma_{}_m"),
                                                        ("velocity", "m/s", "est_sigma_v{}_mps"))):
        pick = log.position_m if quantity == "position" else log.velocity_mps
        error = pick("est") - _truth_at_estimate_time(log, pick("truth"))
        for i in range(3):
            ax = grid[i, col]
            sigma = SIGMA_BAND * log.columns[sigma_fmt.format(AXES[i])]
            if np.isfinite(sigma).any():
                ax.fill_between(log.t_s, -sigma, sigma, color="tab:blue", alpha=0.2, linewidth=0,
                                label=f"±{SIGMA_BAND:g}σ (estimator)")
            ax.plot(log.t_s, error[:, i], color="tab:blue", linewidth=0.9, label="estimate - truth")
            _robust_limits(ax, error[:, i], sigma)
            ax.axhline(0.0, color="black", linewidth=0.5)
            ax.text(0.99, 0.95, f"RMS {_rms(error[:, i]):.3g} {unit}", transform=ax.transAxes, ha="right",
                    va="top", fontsize="small", bbox=dict(facecolor="white", alpha=0.8, linewidth=0))
            ax.set_ylabel(f"{'' if col == 0 else 'v'}{AXES[i]} error ({unit})")
            ax.grid(alpha=0.3)
        grid[0, col].set_title(f"{quantity} error", pad=14)
        _mark_phases(grid[:, col], log)
        grid[-1, col].set_xlabel("time t (s)")
    # one legend for all six panels (they share the same two entries), below them so no data is hidden
    handles, labels = grid[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncols=2, fontsize="small")
    fig.suptitle(f"Estimator error with ±{SIGMA_BAND:g}σ bands: {_flight_name(log)}")
    return fig


def plot_commands(log: FlightLog) -> Figure:
    """Thrust (N) and moments (N m), or attitude commands (deg) when no moments; saturated ticks in red."""
    saturated = log.columns["cmd_saturated"] == 1
    moments = ("cmd_mx_nm", "cmd_my_nm", "cmd_mz_nm")
    fig, (ax_thrust, ax_second) = _figure(2, sharex=True)
    _plot_with_saturation(ax_thrust, log.t_s, log.columns["cmd_thrust_n"], saturated, "thrust", "black")
    ax_thrust.set_ylabel("thrust u1 (N)")
    if not log.has("cmd_thrust_n"):  # attitude-mode logs may carry no thrust column values
        ax_thrust.text(0.5, 0.5, "no thrust command in this log", transform=ax_thrust.transAxes,
                       ha="center", va="center", color="gray")
    if log.has(*moments) or not log.has("cmd_qw", "cmd_qx", "cmd_qy", "cmd_qz"):
        for i, name in enumerate(moments):
            _plot_with_saturation(ax_second, log.t_s, log.columns[name], saturated, f"M{AXES[i]} (body FLU)",
                                  AXIS_COLORS[i])
        ax_second.set_ylabel("moment u2 (N m)")
    else:
        angles_deg = roll_pitch_yaw_deg(log.vec("cmd_qw", "cmd_qx", "cmd_qy", "cmd_qz"))
        for i, name in enumerate(("roll", "pitch", "yaw")):
            _plot_with_saturation(ax_second, log.t_s, angles_deg[:, i], saturated, f"{name} command",
                                  AXIS_COLORS[i])
        ax_second.set_ylabel("attitude command (deg)")
    _mark_phases((ax_thrust, ax_second), log)
    for ax in (ax_thrust, ax_second):
        ax.grid(alpha=0.3)
        _legend(ax, fontsize="small")
    ax_second.set_xlabel("time t (s)")
    fig.suptitle(f"Commands ({int(saturated.sum())} saturated ticks in red): {_flight_name(log)}")
    return fig


def plot_link_health(log: FlightLog, rate_window_s: float = DEFAULT_RATE_WINDOW_S) -> Figure:
    """Downlink rates from the cumulative counters, RTT, mocap age and tick time against time."""
    fig, axes = _figure(4, sharex=True, height_per_panel=2.0)
    ax_rate, ax_rtt, ax_mocap, ax_tick = axes
    t = log.t_s
    received = log.columns["downlink_received"]
    lost = log.columns["downlink_lost"]
    ax_rate.plot(t, windowed_rate(t, received, rate_window_s), color="tab:green", linewidth=1.0,
                 label=f"downlink received ({_last(received):.0f} total)")
    ax_rate.plot(t, windowed_rate(t, lost, rate_window_s), color="tab:red", linewidth=1.0,
                 label=f"downlink lost ({_last(lost):.0f} total{_loss_percent(received, lost)})")
    ax_rate.plot(t, windowed_rate(t, log.columns["uplink_sent"], rate_window_s), color="tab:gray",
                 linewidth=0.8, linestyle=":", label="uplink sent")
    ax_rate.set_ylabel(f"messages/s\n({rate_window_s:g} s window)")
    ax_rtt.plot(t, log.columns["rtt_ms"], color="tab:purple", linewidth=0.9, label="round-trip time")
    ax_rtt.set_ylabel("RTT (ms)")
    _plot_envelope(ax_mocap, t, 1e3 * log.columns["mocap_age_s"], rate_window_s, "mocap age", "tab:brown")
    ax_mocap.set_ylabel("mocap age (ms)")
    tick = log.columns["tick_time_ms"]
    if np.isfinite(tick).any():
        ax_tick.plot(t, tick, color="tab:blue", linewidth=0.9, label="control tick time")
    else:  # lockstep logs leave the wall-clock columns empty so that they depend on the seed alone
        ax_tick.text(0.5, 0.5, "no tick times: a lockstep flight logs no wall-clock time\n(fly with --clock "
                     "realtime to measure them)", transform=ax_tick.transAxes, ha="center", va="center",
                     fontsize="small", color="0.35")
    ax_tick.set_ylabel("tick time (ms)")
    _mark_phases(axes, log)
    for ax in axes:
        ax.grid(alpha=0.3)
        _legend(ax, fontsize="small")
    ax_tick.set_xlabel("time t (s)")
    fig.suptitle(f"Link health: {_flight_name(log)}")
    return fig


def _plot_envelope(ax, t: np.ndarray, values: np.ndarray, window_s: float, label: str, color: str) -> None:
    """A quantity that saws between samples (an age resets at each frame): its min-max band and median over
    windows of window_s, which stays readable where the raw line would fill the panel."""
    known = np.isfinite(values)
    if not known.any():
        return
    edges = np.arange(t[0], t[-1] + window_s, window_s)
    which = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, len(edges) - 1)
    centres, lows, highs, medians = [], [], [], []
    for k in range(len(edges)):
        chunk = values[(which == k) & known]
        if chunk.size:
            centres.append(edges[k] + window_s / 2)
            lows.append(chunk.min())
            highs.append(chunk.max())
            medians.append(np.median(chunk))
    ax.fill_between(centres, lows, highs, color=color, alpha=0.25, linewidth=0,
                    label=f"{label}: min-max per {window_s:g} s")
    ax.plot(centres, medians, color=color, linewidth=1.0, label=f"{label}: median per {window_s:g} s")


def plot_position_velocity(log: FlightLog) -> Figure:
    """Lab report Fig. 2/6 style: x, y, z position (top) and velocity (bottom), reference vs flown."""
    source = _flown_source(log)
    fig, (ax_p, ax_v) = _figure(2, sharex=True, height_per_panel=3.0)
    for ax, pick in ((ax_p, log.position_m), (ax_v, log.velocity_mps)):
        ref, flown = pick("ref"), pick(source)
        for i in range(3):
            ax.plot(log.t_s, flown[:, i], color=AXIS_COLORS[i], linewidth=1.2, label=f"{AXES[i]} flown")
            ax.plot(log.t_s, ref[:, i], color=AXIS_COLORS[i], linewidth=1.0, linestyle="--",
                    label=f"{AXES[i]} reference")
        ax.grid(alpha=0.3)
        _legend(ax, fontsize="small", ncols=3)
    _mark_phases((ax_p, ax_v), log)
    ax_p.set_ylabel("position (m)")
    ax_v.set_ylabel("velocity (m/s)")
    ax_v.set_xlabel("time t (s)")
    fig.suptitle(f"Position and velocity, reference (dashed) vs flown ({SOURCE_STYLE[source]['label']}): "
                 f"{_flight_name(log)}")
    return fig


# ---------------------------------------------------------------- 3D world view


def plot_trajectory_3d(log: FlightLog, world: World | None) -> Figure:
    """3D view: world blocks, A* path, waypoints, reference and flown trajectory, equal aspect."""
    plan = log.plan
    fig = Figure(figsize=(9.0, 7.5), dpi=FIG_DPI)
    ax = fig.add_subplot(projection="3d")
    if world is not None:
        _draw_blocks(ax, world)
    flown_source = _flown_source(log)
    ref, flown = log.position_m("ref"), log.position_m(flown_source)
    if plan is not None and len(plan.path_m):
        ax.plot(*plan.path_m.T, color="tab:gray", linewidth=0.8, label="A* path")
    if plan is not None and len(plan.waypoints_m):
        ax.scatter(*plan.waypoints_m.T, color="tab:purple", s=18, depthshade=False, label="waypoints")
    ax.plot(*ref.T, color="black", linestyle="--", linewidth=1.0, label="reference")
    flown_label = f"flown ({SOURCE_STYLE[flown_source]['label']})"
    ax.plot(*flown.T, color="tab:orange", linewidth=1.4, label=flown_label)
    if world is not None:
        for name, point, marker in (("start", world.start, "o"), ("goal", world.goal, "*")):
            if point is not None:
                ax.scatter(*point, color="tab:green" if name == "start" else "tab:red", marker=marker, s=60,
                           depthshade=False, label=name)
    _equal_aspect(ax, world, [ref, flown] + ([plan.path_m, plan.waypoints_m] if plan is not None else []))
    ax.set_xlabel("x east (m)")
    ax.set_ylabel("y north (m)")
    ax.set_zlabel("z up (m)")
    _legend(ax, fontsize="small", loc="upper left")
    title = f"Flown trajectory through {Path(str(plan.world_path)).name if plan else 'world'}"
    if plan is not None and plan.trajectory:
        title += f" ({plan.trajectory} trajectory)"
    ax.set_title(f"{title}: {_flight_name(log)}")
    return fig


def plot_trajectory_top(log: FlightLog, world: World | None) -> Figure:
    """Top-down view (x east, y north): blocks as their footprints (darker = taller), A* path, waypoints,
    reference and flown path, so a maze's 3 m walls cannot hide the path as they do in the 3-D view."""
    plan = log.plan
    fig = Figure(figsize=(9.0, 7.0), dpi=FIG_DPI, layout="constrained")  # room for the legend beside the map
    ax = fig.add_subplot()
    if world is not None:
        _draw_footprints(ax, world)
    flown_source = _flown_source(log)
    ref, flown = log.position_m("ref"), log.position_m(flown_source)
    if plan is not None and len(plan.path_m):
        ax.plot(*plan.path_m[:, :2].T, color="tab:gray", linewidth=0.8, label="A* path")
    if plan is not None and len(plan.waypoints_m):
        ax.scatter(*plan.waypoints_m[:, :2].T, color="tab:purple", s=18, zorder=3, label="waypoints")
    ax.plot(*ref[:, :2].T, color="black", linestyle="--", linewidth=1.0, label="reference")
    ax.plot(*flown[:, :2].T, color="tab:orange", linewidth=1.4, label=f"flown ({SOURCE_STYLE[flown_source]['label']})")
    if world is not None:
        for name, point, marker in (("start", world.start, "o"), ("goal", world.goal, "*")):
            if point is not None:
                ax.scatter(point[0], point[1], color="tab:green" if name == "start" else "tab:red", marker=marker,
                           s=80, zorder=4, label=name)
        ax.set_xlim(world.bounds[0], world.bounds[1])
        ax.set_ylim(world.bounds[2], world.bounds[3])
    ax.set_aspect("equal")
    ax.set_xlabel("x east (m)")
    ax.set_ylabel("y north (m)")
    ax.grid(alpha=0.3)
    _legend(ax, fontsize="small", loc="upper left", bbox_to_anchor=(1.01, 1.0))  # beside the map, hiding none of it
    name = Path(str(plan.world_path)).name if plan else "world"
    ax.set_title(f"Top-down view of {name}: {_flight_name(log)}")
    return fig


def _draw_footprints(ax, world: World) -> None:
    """Each block's x-y rectangle, shaded by its top height over the world's height (taller is darker)."""
    z_low, z_high = float(world.bounds[4]), float(world.bounds[5])
    for xmin, xmax, ymin, ymax, _, zmax in np.asarray(world.blocks, float).reshape(-1, 6):
        shade = 0.25 + 0.6 * np.clip((zmax - z_low) / max(z_high - z_low, 1e-9), 0.0, 1.0)
        ax.add_patch(Rectangle((xmin, ymin), xmax - xmin, ymax - ymin, facecolor=(0.3, 0.3, 0.35, shade),
                               edgecolor="none"))


def block_color(color: object) -> tuple[float, float, float]:
    """A world block's colour as RGB 0-1 from RGB 0-1, RGB 0-255 or a matplotlib colour name; else grey."""
    fallback = mcolors.to_rgb(UNKNOWN_BLOCK_COLOR)
    if isinstance(color, str):
        try:
            return mcolors.to_rgb(color)
        except ValueError:
            return fallback
    if isinstance(color, (list, tuple)) and len(color) == 3 and all(
            isinstance(c, (int, float)) and not isinstance(c, bool) for c in color):
        rgb = np.asarray(color, float)
        if not np.isfinite(rgb).all() or rgb.min() < 0:
            return fallback
        if rgb.max() <= 1.0:
            return tuple(rgb)
        if rgb.max() <= 255.0:
            return tuple(rgb / 255.0)
    return fallback


def box_faces(extents: np.ndarray) -> list[np.ndarray]:
    """The 6 faces (each 4x3 corner array) of an axis-aligned box [xmin, xmax, ymin, ymax, zmin, zmax]."""
    x0, x1, y0, y1, z0, z1 = extents
    corners = np.array([[x, y, z] for z in (z0, z1) for y in (y0, y1) for x in (x0, x1)])
    # corner index = 4*iz + 2*iy + ix; each face listed in order around its edge
    faces = ((0, 1, 3, 2), (4, 5, 7, 6), (0, 1, 5, 4), (2, 3, 7, 6), (0, 2, 6, 4), (1, 3, 7, 5))
    return [corners[list(f)] for f in faces]


def _draw_blocks(ax, world: World) -> None:
    if not len(world.blocks):
        return
    faces, face_colors = [], []
    for i, extents in enumerate(world.blocks):
        rgb = block_color(world.colors[i] if i < len(world.colors) else None)
        faces += box_faces(extents)
        face_colors += [(*rgb, BLOCK_ALPHA)] * 6
    ax.add_collection3d(Poly3DCollection(faces, facecolors=face_colors, edgecolors=(0, 0, 0, 0.15),
                                         linewidths=0.3))


def _equal_aspect(ax, world: World | None, point_sets: list[np.ndarray]) -> None:
    """Axis limits covering the world bounds and everything drawn, with 1 m the same length on each axis."""
    points = [p[np.isfinite(p).all(axis=1)] for p in point_sets if len(p)]
    if world is not None:
        points.append(world.bounds.reshape(3, 2).T)
    points = [p for p in points if len(p)]
    if not points:
        return
    stacked = np.vstack(points)
    lo, hi = stacked.min(axis=0), stacked.max(axis=0)
    span = np.maximum(hi - lo, 1e-3)  # a flat world still needs a drawable axis
    ax.set_xlim(lo[0], lo[0] + span[0])
    ax.set_ylim(lo[1], lo[1] + span[1])
    ax.set_zlim(lo[2], lo[2] + span[2])
    ax.set_box_aspect(tuple(span))


def _load_plan_world(log: FlightLog) -> tuple[World | None, str]:
    """The planned world, or None with a note (the 3D view is still drawn, without blocks)."""
    try:
        return load_world(log.plan.world_path), ""
    except WorldError as err:
        return None, f"trajectory_3d.png drawn without blocks: {err}"


# ---------------------------------------------------------------- helpers


def windowed_rate(t_s: np.ndarray, counter: np.ndarray, window_s: float) -> np.ndarray:
    """Rate (1/s) of a cumulative counter: (c(t) - c(t - W)) / (actual elapsed time), NaN where unknown.

    Differencing over a window W rather than tick to tick, because per tick the counter moves in
    integer steps and the rate would jump between 0 and several times its mean.
    """
    rate = np.full(len(t_s), np.nan)
    known = np.isfinite(counter)
    if known.sum() < 2:
        return rate
    t, c = t_s[known], counter[known]
    start = np.searchsorted(t, t - window_s, side="left")
    elapsed = t - t[start]
    with np.errstate(invalid="ignore", divide="ignore"):
        rate[known] = np.where(elapsed > 0, (c - c[start]) / elapsed, np.nan)
    return rate


def _plot_with_saturation(ax, t, values, saturated, label, color) -> None:
    ax.plot(t, values, color=color, linewidth=1.0, label=label)
    marked = saturated & np.isfinite(values)
    if marked.any():
        first = SATURATED_LABEL not in ax.get_legend_handles_labels()[1]  # one legend entry per panel
        ax.plot(t[marked], values[marked], linestyle="none", marker="o", markersize=3, color="red",
                label=SATURATED_LABEL if first else None)


def _shade_phases(ax, log: FlightLog) -> None:
    """Background span per run of one phase word, one legend entry per phase."""
    if not len(log.phase):
        return
    changes = np.flatnonzero(log.phase[1:] != log.phase[:-1]) + 1
    starts = np.concatenate([[0], changes])
    ends = np.concatenate([changes, [len(log.phase)]])
    labelled: set[str] = set()
    for s, e in zip(starts, ends, strict=True):
        phase = str(log.phase[s]) or "unknown"
        t_end = log.t_s[e] if e < len(log.t_s) else log.t_s[-1]
        ax.axvspan(log.t_s[s], t_end, color=PHASE_COLORS.get(phase, "#f7f7f7"), alpha=0.6, linewidth=0,
                   label=None if phase in labelled else f"phase: {phase}")
        labelled.add(phase)


def _mark_phases(axes, log: FlightLog) -> None:
    """A dotted line at each change of flight phase on every panel, named above the first panel."""
    if not len(log.phase):
        return
    changes = np.flatnonzero(log.phase[1:] != log.phase[:-1]) + 1
    first = True
    for ax in axes:
        for index in changes:
            ax.axvline(log.t_s[index], color="gray", linestyle=":", linewidth=0.8)
            if first:
                ax.text(log.t_s[index], 1.0, f" {log.phase[index]}", transform=ax.get_xaxis_transform(),
                        rotation=90, va="bottom", ha="center", fontsize="x-small", color="dimgray", clip_on=False)
        first = False


def _flown_source(log: FlightLog) -> str:
    return "truth" if log.has_truth else "est"


def _rms(values: np.ndarray) -> float:
    known = values[np.isfinite(values)]
    return float(np.sqrt(np.mean(known**2))) if len(known) else float("nan")


def _last(values: np.ndarray) -> float:
    known = values[np.isfinite(values)]
    return float(known[-1]) if len(known) else float("nan")


def _loss_percent(received: np.ndarray, lost: np.ndarray) -> str:
    total = _last(received) + _last(lost)
    return f", {100.0 * _last(lost) / total:.1f} %" if np.isfinite(total) and total > 0 else ""


def _flight_name(log: FlightLog) -> str:
    name = log.folder.resolve().name
    result = (log.summary or {}).get("result")
    return f"{name} ({result})" if isinstance(result, str) and result else name


def _figure(nrows: int, ncols: int = 1, sharex: bool = False, height_per_panel: float = 2.4):
    fig = Figure(figsize=(10.0 if ncols == 1 else 12.0, 1.2 + height_per_panel * nrows), dpi=FIG_DPI,
                 layout="constrained")
    axes = fig.subplots(nrows, ncols, sharex=sharex, squeeze=False)
    return fig, (axes[:, 0] if ncols == 1 else axes)


def _legend(ax, **kwargs) -> None:
    """A legend only when something is labelled (an all-empty column draws nothing)."""
    handles, labels = ax.get_legend_handles_labels()
    if handles:
        ax.legend(handles, labels, **kwargs)


def _save(fig: Figure, path: Path) -> Path:
    FigureCanvasAgg(fig)
    try:
        fig.savefig(path, format="png")
    except OSError as err:
        raise UserError(f"{path}: cannot write ({err.strerror})") from None
    return path
