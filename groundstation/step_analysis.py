"""Second-order step-response metrics of one axis, as the lab report computes them (section II, Fig. 1).

Takes in: a time series (t_s, y_m) of the commanded axis (s, m) and the step: its time, the value before
(y0) and the commanded target; a settling band (fraction of the step, default 5 %) and the fraction of
the post-step record averaged as the steady state.
Gives out: StepMetrics (steady-state error, overshoot in m and %, damping ratio from the overshoot, peak
time, rise time to the final value and 10-90 % rise time, settling time, all times measured from the
step), and `plot_step`, a PNG like the report's Fig. 1.

Definitions (report, section II):
    final value y_ss = mean of the last part of the record; steady-state error = y_target - y_ss
    overshoot = peak - y_ss;  PO = overshoot / (y_ss - y0) * 100
    zeta = -ln(PO/100) / sqrt(pi^2 + ln(PO/100)^2)
    rise time = time to FIRST reach y_ss; settling time = time after which y stays within the band.
The report quotes PO = 0.15/0.455 x 100 = 32 % and zeta = 0.3409598. That zeta is the formula at exactly
PO = 32 %; at the unrounded PO = 32.967 % the same formula gives zeta = 0.3331. This module does not round.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from model.errors import UserError

DEFAULT_SETTLING_BAND = 0.05  # fraction of the step (y_ss - y0); the report's Fig. 1 band
DEFAULT_TAIL_FRACTION = 0.2  # last fifth of the post-step record is the steady state
RISE_LOW, RISE_HIGH = 0.1, 0.9  # the conventional 10-90 % rise time


@dataclass(frozen=True)
class StepMetrics:
    step_time_s: float
    initial_m: float  # y0, before the step
    target_m: float  # commanded value after the step
    final_value_m: float  # y_ss, mean of the tail of the record
    steady_state_error_m: float  # y_target - y_ss
    peak_m: float  # extreme value in the step direction
    peak_time_s: float  # from the step
    overshoot_m: float  # peak beyond y_ss in the step direction (0 if none)
    percent_overshoot: float  # overshoot / (y_ss - y0) * 100
    damping_ratio: float  # from PO; nan without overshoot (critically or over-damped)
    natural_frequency_radps: float  # pi / (t_peak sqrt(1 - zeta^2)); nan without overshoot
    rise_time_s: float  # from the step to first reaching y_ss (nan if never)
    rise_time_10_90_s: float  # from 10 % to 90 % of y_ss - y0
    settling_time_s: float  # from the step until y stays within the band (nan if it never settles)
    settling_band_m: float  # half-width of the band around y_ss


def damping_ratio_from_overshoot(percent_overshoot: float) -> float:
    """zeta = -ln(PO/100) / sqrt(pi^2 + ln(PO/100)^2) for 0 < PO < 100; nan outside (no oscillation)."""
    if not 0.0 < percent_overshoot < 100.0:
        return math.nan
    log_po = math.log(percent_overshoot / 100.0)
    return -log_po / math.sqrt(math.pi**2 + log_po**2)


def _first_reach(t: np.ndarray, u: np.ndarray, level: float) -> float:
    """First time u (rising towards 1) reaches `level`, interpolated between samples; nan if never."""
    above = np.nonzero(u >= level)[0]
    if above.size == 0:
        return math.nan
    i = int(above[0])
    if i == 0:
        return float(t[0])
    return float(np.interp(level, [u[i - 1], u[i]], [t[i - 1], t[i]]))


def _settling_time(t: np.ndarray, u: np.ndarray, band: float) -> float:
    """Time from which |u - 1| <= band for the rest of the record; nan if the last sample is outside."""
    outside = np.nonzero(np.abs(u - 1.0) > band)[0]
    if outside.size == 0:
        return float(t[0])
    k = int(outside[-1])
    if k == len(u) - 1:
        return math.nan
    boundary = 1.0 + math.copysign(band, u[k] - 1.0)  # the edge of the band it crossed
    fraction = (boundary - u[k]) / (u[k + 1] - u[k])  # in (0, 1]: u[k] is outside, u[k + 1] inside
    return float(t[k] + fraction * (t[k + 1] - t[k]))


def analyze_step(t_s: np.ndarray, y_m: np.ndarray, step_time_s: float, initial_m: float, target_m: float,
                 settling_band: float = DEFAULT_SETTLING_BAND,
                 tail_fraction: float = DEFAULT_TAIL_FRACTION) -> StepMetrics:
    """Step-response metrics of y(t) for a step from initial_m to target_m at step_time_s."""
    t = np.asarray(t_s, dtype=float)
    y = np.asarray(y_m, dtype=float)
    if t.ndim != 1 or t.shape != y.shape:
        raise UserError(f"step analysis: t and y must be 1-D of equal length, got {t.shape} and {y.shape}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(y))) or np.any(np.diff(t) <= 0):
        raise UserError("step analysis: times must be finite and strictly increasing, values finite")
    if target_m == initial_m:
        raise UserError("step analysis: the step size (target - initial) is zero")
    if not (0.0 < settling_band < 1.0 and 0.0 < tail_fraction <= 1.0):
        raise UserError(f"step analysis: settling_band {settling_band} and tail_fraction {tail_fraction} "
                        "must lie in (0, 1)")
    after = t >= step_time_s
    if np.count_nonzero(after) < 3:
        raise UserError(f"step analysis: fewer than 3 samples after the step at {step_time_s} s")
    t_after, y_after = t[after] - step_time_s, y[after]

    tail = t_after >= (1.0 - tail_fraction) * t_after[-1]
    final = float(np.mean(y_after[tail]))
    change = final - initial_m
    direction = math.copysign(1.0, target_m - initial_m)
    if change * direction <= 0.0:  # it never moved towards the target: nothing second-order to measure
        u = None
    else:
        u = (y_after - initial_m) / change  # normalised: 0 before, 1 at the final value

    i_peak = int(np.argmax(y_after * direction))
    peak = float(y_after[i_peak])
    nan = math.nan
    if u is None:
        overshoot = po = zeta = wn = rise = rise_10_90 = settle = nan
    else:
        overshoot = max(0.0, (peak - final) * direction)
        po = overshoot / abs(change) * 100.0
        zeta = damping_ratio_from_overshoot(po)
        t_peak = float(t_after[i_peak])
        wn = math.pi / (t_peak * math.sqrt(1.0 - zeta**2)) if math.isfinite(zeta) and t_peak > 0 else nan
        rise = _first_reach(t_after, u, 1.0)
        rise_10_90 = _first_reach(t_after, u, RISE_HIGH) - _first_reach(t_after, u, RISE_LOW)
        settle = _settling_time(t_after, u, settling_band)
    return StepMetrics(
        step_time_s=float(step_time_s), initial_m=float(initial_m), target_m=float(target_m),
        final_value_m=final, steady_state_error_m=float(target_m) - final,
        peak_m=peak, peak_time_s=float(t_after[i_peak]), overshoot_m=overshoot, percent_overshoot=po,
        damping_ratio=zeta, natural_frequency_radps=wn, rise_time_s=rise, rise_time_10_90_s=rise_10_90,
        settling_time_s=settle, settling_band_m=settling_band * abs(change),
    )


def plot_step(t_s: np.ndarray, y_m: np.ndarray, metrics: StepMetrics, path: str | Path,
              axis_name: str = "y", title: str | None = None) -> Path:
    """Write a PNG like the report's Fig. 1: response, reference, steady-state band and the metrics."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    m = metrics
    t = np.asarray(t_s, dtype=float)
    fig, ax = plt.subplots(figsize=(8, 4.5), dpi=120)
    try:
        ax.plot(t, y_m, color="tab:blue", label=f"response {axis_name}")
        ax.step([t[0], m.step_time_s, t[-1]], [m.initial_m, m.target_m, m.target_m], where="post",
                color="k", linestyle="--", label="reference")
        ax.axhline(m.final_value_m, color="tab:green", linewidth=0.8,
                   label=f"final value {m.final_value_m:.3f} m")
        ax.axhspan(m.final_value_m - m.settling_band_m, m.final_value_m + m.settling_band_m,
                   color="tab:green", alpha=0.15, label=f"settling band \u00b1{m.settling_band_m:.3f} m")
        if math.isfinite(m.percent_overshoot) and m.overshoot_m > 0:
            ax.plot([m.step_time_s + m.peak_time_s], [m.peak_m], "o", color="tab:blue", label="peak")
        for value, label, color in ((m.rise_time_s, "rise (first reach)", "tab:orange"),
                                    (m.settling_time_s, "settling", "tab:red")):
            if math.isfinite(value):
                ax.axvline(m.step_time_s + value, color=color, linestyle=":",
                           label=f"{label} time {value:.2f} s after the step")
        # The figures in a box inside the axes (top left, where a step up leaves room), never beside a point
        # near the edge, where they would run off the plot.
        lines = [f"overshoot {m.overshoot_m:.3f} m (PO {m.percent_overshoot:.1f} %)",
                 f"damping ratio {m.damping_ratio:.3f}" if math.isfinite(m.damping_ratio) else "no overshoot",
                 f"rise (first reach) {m.rise_time_s:.2f} s, 10-90 % {m.rise_time_10_90_s:.2f} s",
                 f"settling {m.settling_time_s:.2f} s", f"steady-state error {m.steady_state_error_m:.3f} m"]
        rising = m.target_m >= m.initial_m
        ax.text(0.02, 0.97 if rising else 0.03, "\n".join(lines), transform=ax.transAxes, fontsize="small",
                va="top" if rising else "bottom", ha="left", bbox={"boxstyle": "round", "fc": "white", "alpha": 0.85})
        ax.set_xlabel("time (s)")
        ax.set_ylabel(f"{axis_name} position (m)")
        ax.set_title(title or f"Step response in {axis_name}")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="lower right", fontsize="small")
        fig.tight_layout()
        path = Path(path)
        fig.savefig(path)
    finally:
        plt.close(fig)
    return path
