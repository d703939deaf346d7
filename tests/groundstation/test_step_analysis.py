"""Step metrics against the analytic second-order step response and the lab report's definitions."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from groundstation.step_analysis import analyze_step, damping_ratio_from_overshoot, plot_step
from model.errors import UserError

DT = 1e-3


def second_order(t: np.ndarray, zeta: float, wn: float) -> np.ndarray:
    """Unit step response of wn^2 / (s^2 + 2 zeta wn s + wn^2), underdamped; 0 for t < 0."""
    wd = wn * math.sqrt(1.0 - zeta**2)
    tt = np.maximum(t, 0.0)
    y = 1.0 - np.exp(-zeta * wn * tt) * (np.cos(wd * tt) + zeta / math.sqrt(1.0 - zeta**2) * np.sin(wd * tt))
    return np.where(t >= 0.0, y, 0.0)


def record(zeta, wn, y0=0.2, final=0.7, step_at=1.5):
    """Sampled response long enough for the envelope exp(-zeta wn t) to fall below 1e-8: a settled tail."""
    t = np.arange(0.0, step_at + 18.5 / (zeta * wn), DT)
    return t, y0 + (final - y0) * second_order(t - step_at, zeta, wn)


@pytest.mark.parametrize("zeta, wn", [(0.2, 4.0), (0.34, 3.0), (0.6, 6.0)])
def test_metrics_match_second_order_theory(zeta, wn):
    y0, final, step_at = 0.2, 0.7, 1.5
    t, y = record(zeta, wn, y0, final, step_at)
    m = analyze_step(t, y, step_at, y0, final)
    wd = wn * math.sqrt(1 - zeta**2)
    po = 100 * math.exp(-math.pi * zeta / math.sqrt(1 - zeta**2))
    assert m.final_value_m == pytest.approx(final, abs=1e-6)
    assert m.steady_state_error_m == pytest.approx(0.0, abs=1e-6)
    assert m.percent_overshoot == pytest.approx(po, rel=1e-4)
    assert m.overshoot_m == pytest.approx(po / 100 * (final - y0), rel=1e-4)
    assert m.peak_time_s == pytest.approx(math.pi / wd, abs=DT)
    assert m.damping_ratio == pytest.approx(zeta, rel=1e-4)
    assert m.natural_frequency_radps == pytest.approx(wn, rel=1e-2)
    # Rise time to the final value: cos(wd t) + zeta/sqrt(1-zeta^2) sin(wd t) = 0 first at
    # t = (pi - acos zeta) / wd.
    assert m.rise_time_s == pytest.approx((math.pi - math.acos(zeta)) / wd, abs=1e-4)
    # 10-90 % rise time: solve the analytic response for both levels.
    first_peak = math.pi / wd
    t10 = brentq(lambda s: second_order(np.array([s]), zeta, wn)[0] - 0.1, 0.0, first_peak)
    t90 = brentq(lambda s: second_order(np.array([s]), zeta, wn)[0] - 0.9, 0.0, first_peak)
    assert m.rise_time_10_90_s == pytest.approx(t90 - t10, abs=1e-4)


@pytest.mark.parametrize("band", [0.02, 0.05])
def test_settling_time_is_the_last_exit_from_the_band(band):
    zeta, wn = 0.3, 4.0
    t, y = record(zeta, wn, 0.0, 1.0, 0.0)
    m = analyze_step(t, y, 0.0, 0.0, 1.0, settling_band=band)
    assert m.settling_band_m == pytest.approx(band, rel=1e-6)
    ts = m.settling_time_s
    # On the analytic response: on the band's edge at ts, inside for all later times, outside just before.
    fine = np.linspace(ts, ts + 10.0, 200001)
    assert abs(abs(second_order(np.array([ts]), zeta, wn)[0] - 1.0) - band) < 1e-5
    assert np.all(np.abs(second_order(fine[1:], zeta, wn) - 1.0) <= band + 1e-6)
    before = np.linspace(ts - 0.3, ts - 1e-3, 500)
    assert np.any(np.abs(second_order(before, zeta, wn) - 1.0) > band)
    # And within the classical envelope bound exp(-zeta wn t)/sqrt(1 - zeta^2) = band.
    assert ts <= -math.log(band * math.sqrt(1 - zeta**2)) / (zeta * wn)


def test_report_figures_and_the_damping_formula():
    # Report: "overshoot 0.15 m so PO = 0.15/0.455 x 100 = 32%", zeta = 0.3409598. That zeta is the
    # formula at PO = 32 % exactly; the unrounded PO = 32.967 % gives zeta = 0.3331.
    def formula(po):
        log_po = math.log(po / 100)
        return -log_po / math.sqrt(math.pi**2 + log_po**2)

    assert damping_ratio_from_overshoot(32.0) == pytest.approx(0.3409598, abs=1e-7)
    assert damping_ratio_from_overshoot(0.15 / 0.455 * 100) == pytest.approx(formula(0.15 / 0.455 * 100))
    assert damping_ratio_from_overshoot(0.15 / 0.455 * 100) == pytest.approx(0.3331, abs=1e-4)
    # A record shaped like the report's Fig. 1: 0.5 m step in y at 1.5 s, settling 0.045 m short (0.455 m
    # travelled), peaking 0.15 m above the final value.
    zeta = formula(0.15 / 0.455 * 100)
    t, y = record(zeta, 3.0, y0=0.0, final=0.455, step_at=1.5)
    m = analyze_step(t, y, 1.5, 0.0, 0.5)
    assert m.steady_state_error_m == pytest.approx(0.045, abs=1e-5)
    assert m.overshoot_m == pytest.approx(0.15, rel=1e-4)
    assert m.percent_overshoot == pytest.approx(0.15 / 0.455 * 100, rel=1e-4)
    assert m.damping_ratio == pytest.approx(zeta, rel=1e-4)


def test_downward_step_mirrors_an_upward_one():
    t, up = record(0.4, 5.0, 1.0, 1.5)
    down = 2.0 - up  # from 1.0 to 0.5
    m_up = analyze_step(t, up, 1.5, 1.0, 1.5)
    m_down = analyze_step(t, down, 1.5, 1.0, 0.5)
    for field in ("overshoot_m", "percent_overshoot", "damping_ratio", "rise_time_s", "settling_time_s",
                  "peak_time_s"):
        assert getattr(m_down, field) == pytest.approx(getattr(m_up, field), rel=1e-9), field
    assert m_down.steady_state_error_m == pytest.approx(-m_up.steady_state_error_m, abs=1e-9)


def test_critically_damped_response_has_no_overshoot():
    t = np.arange(0.0, 20.0, DT)
    y = 1.0 - np.exp(-2.0 * t) * (1 + 2.0 * t)  # critically damped, wn = 2: approaches 1 from below
    m = analyze_step(t, y, 0.0, 0.0, 1.0)
    assert m.percent_overshoot < 1e-9  # rounding of a settled tail at most
    # No overshoot means zeta >= 1: the formula is undefined (nan) or tends to 1 as PO -> 0.
    assert math.isnan(m.damping_ratio) or m.damping_ratio > 0.95


def test_noise_barely_moves_the_steady_state():
    rng = np.random.default_rng(3)
    t, y = record(0.5, 4.0, 0.0, 1.0, 1.0)
    m = analyze_step(t, y + rng.normal(0.0, 0.005, t.size), 1.0, 0.0, 1.0)
    # Mean of ~2000 samples: standard error 0.005 / sqrt(2000) ~ 1e-4 m.
    assert m.final_value_m == pytest.approx(1.0, abs=6e-4)


def test_never_settling_and_bad_input():
    t = np.arange(0.0, 5.0, DT)
    y = np.where(t >= 1.0, 1.0 + 0.2 * np.sin(8.0 * t), 0.0)  # undamped oscillation about 1
    assert math.isnan(analyze_step(t, y, 1.0, 0.0, 1.0).settling_time_s)
    with pytest.raises(UserError, match="step size"):
        analyze_step(t, y, 1.0, 0.0, 0.0)
    with pytest.raises(UserError, match="strictly increasing"):
        analyze_step(t[::-1], y, 1.0, 0.0, 1.0)
    with pytest.raises(UserError, match="fewer than 3 samples"):
        analyze_step(t, y, 10.0, 0.0, 1.0)


def test_plot_writes_a_png(tmp_path):
    t, y = record(0.34, 3.0, 0.0, 0.455, 1.5)
    m = analyze_step(t, y, 1.5, 0.0, 0.5)
    path = plot_step(t, y, m, tmp_path / "step.png", axis_name="y")
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000


@pytest.mark.parametrize("size", [0.5, -0.5])
def test_the_plots_figures_stay_inside_the_axes(tmp_path, monkeypatch, size):
    import matplotlib.pyplot as plt

    kept = []
    monkeypatch.setattr(plt, "close", kept.append)  # keep the figure to measure where its texts landed
    t, y = record(0.34, 3.0, 0.0, size * 0.91, 1.5)
    m = analyze_step(t, y, 1.5, 0.0, size)
    plot_step(t, y, m, tmp_path / "step.png", axis_name="y")
    fig = kept[0]
    ax = fig.axes[0]
    renderer = fig.canvas.get_renderer()
    box = ax.get_window_extent(renderer)
    texts = ax.texts
    assert texts and all(text.get_window_extent(renderer).fully_overlaps(box) for text in texts)
    inside = [box.contains(*corner) for text in texts for corner in text.get_window_extent(renderer).corners()]
    assert all(inside)
    assert "rise (first reach)" in texts[0].get_text() and "10-90 %" in texts[0].get_text()
    monkeypatch.undo()
    plt.close(fig)
