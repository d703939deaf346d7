"""The stability-map PNG: per panel (mode, and any other axis swept with more than one value), a latency x
loss map of the success rate over seeds, and beneath it the spread over seeds of the max tracking error.

Takes in: the sweep's rows (groundstation.sweep.table) and its SweepOptions (for the title).
Gives out: sweep.png. Top row: colour = success rate (0-100 %), text = successes/seeds. Bottom row: colour
= sample standard deviation over the successful seeds of the max tracking error (m), text = its median;
"n<2" where fewer than two seeds succeeded (text: spread and median, mm), "-" where nothing was flown.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.cm import ScalarMappable
from matplotlib.colors import Normalize
from matplotlib.figure import Figure

from groundstation.sweep.grid import SweepOptions, num
from groundstation.sweep.table import panel_title, panels, varying_axes

FIG_DPI = 110
MM_PER_M = 1000.0
PCT = 100.0
RATE_CMAP = "RdYlGn"
SPREAD_CMAP = "viridis"


def _grid(cells: Mapping[tuple[float, float], dict], lats, losses, key: str) -> np.ndarray:
    grid = np.full((len(losses), len(lats)), np.nan)
    for (lat, loss), agg in cells.items():
        if agg.get(key) is not None:
            grid[losses.index(loss), lats.index(lat)] = agg[key]
    return grid


def _axes_labels(ax, lats: Sequence[float], losses: Sequence[float]) -> None:
    ax.set_xticks(range(len(lats)), labels=[num(v) for v in lats])
    ax.set_yticks(range(len(losses)), labels=[num(v) for v in losses])
    ax.set_xlim(-0.5, len(lats) - 0.5)
    ax.set_ylim(-0.5, len(losses) - 0.5)
    ax.set_xlabel("one-way latency, each direction (ms)")
    ax.set_ylabel("average frame loss, each direction (%)")


def _draw(ax, grid: np.ndarray, cmap, norm) -> None:
    rows, cols = grid.shape
    ax.pcolormesh(np.arange(cols + 1) - 0.5, np.arange(rows + 1) - 0.5, np.ma.masked_invalid(grid), cmap=cmap,
                  norm=norm)


def plot_sweep(rows: Sequence[Mapping], opts: SweepOptions, path: Path) -> Path:
    maps = panels(rows)
    varying = varying_axes(maps)
    spreads = [a["max_error_spread_m"] for cells in maps.values() for a in cells.values()
               if a["max_error_spread_m"] is not None]
    spread_norm = Normalize(0.0, MM_PER_M * max(spreads) if spreads and max(spreads) > 0 else 1.0)
    rate_norm = Normalize(0.0, PCT)
    n = max(1, len(maps))
    all_lats = sorted({lat for cells in maps.values() for lat, _ in cells}) or [0.0]
    all_losses = sorted({loss for cells in maps.values() for _, loss in cells}) or [0.0]
    panel_w, panel_h = max(4.0, 0.8 * len(all_lats) + 1.8), max(3.0, 0.55 * len(all_losses) + 1.8)
    fig = Figure(figsize=(panel_w * n + 1.5, 2 * panel_h + 1.0), dpi=FIG_DPI, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, n, squeeze=False)
    for col, (panel, cells) in enumerate(maps.items()):
        lats, losses = sorted({lat for lat, _ in cells}), sorted({loss for _, loss in cells})
        rate_ax, spread_ax = axes[0][col], axes[1][col]
        rates = _grid(cells, lats, losses, "success_rate") * PCT
        _draw(rate_ax, rates, colormaps[RATE_CMAP], rate_norm)
        spread_mm = MM_PER_M * _grid(cells, lats, losses, "max_error_spread_m")
        _draw(spread_ax, spread_mm, colormaps[SPREAD_CMAP], spread_norm)
        for (lat, loss), agg in cells.items():
            x, y = lats.index(lat), losses.index(loss)
            rate_ax.text(x, y, f"{agg['successes']}/{agg['flights']}", ha="center", va="center", fontsize="small")
            median, spread = agg["max_error_median_m"], agg["max_error_spread_m"]
            label = "n<2" if spread is None else f"sd {MM_PER_M * spread:.1f} mm"
            if median is not None:
                label += f"\nmedian {MM_PER_M * median:.0f} mm"
            spread_ax.text(x, y, label, ha="center", va="center", fontsize="x-small",
                           color="white" if spread is not None and spread_norm(MM_PER_M * spread) < 0.5 else "black")
        for ax in (rate_ax, spread_ax):
            _axes_labels(ax, lats, losses)
        rate_ax.set_title(f"{panel_title(panel, varying)}\nsuccess rate over seeds", fontsize="small")
        spread_ax.set_title("max tracking error over the successful seeds", fontsize="small")
    fig.colorbar(ScalarMappable(norm=rate_norm, cmap=colormaps[RATE_CMAP]), ax=list(axes[0]),
                 label="success rate (%): goal reached, no collision")
    fig.colorbar(ScalarMappable(norm=spread_norm, cmap=colormaps[SPREAD_CMAP]), ax=list(axes[1]),
                 label="max tracking error: std dev over seeds (mm)")
    seeds = f"seeds {opts.seeds[0]}..{opts.seeds[-1]}" if len(opts.seeds) > 1 else f"seed {opts.seeds[0]}"
    fig.suptitle(f"Stability map ({seeds}, lockstep clock, firmware {opts.firmware})", fontsize="medium")
    fig.savefig(path)
    return path
