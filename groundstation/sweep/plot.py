"""The stability-map PNG: one heatmap per mode, x = one-way latency (ms), y = loss (%), colour = max
tracking error (m); failed cells hatched and marked X, cells not flown marked -.

Takes in: the cell results and the SweepOptions (axes, world, base radio, seed).
Gives out: sweep.png.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.cm import ScalarMappable
from matplotlib.colors import LogNorm, Normalize
from matplotlib.figure import Figure
from matplotlib.patches import Patch, Rectangle

from groundstation.sweep.grid import SweepOptions, _num
from groundstation.sweep.table import CellResult

FIG_DPI = 110


def _colour_norm(values: Sequence[float]) -> Normalize:
    """Log colours when the errors span more than a decade (a few mm to tens of cm), linear otherwise."""
    if not values:
        return Normalize(0.0, 1.0)
    low, high = min(values), max(values)
    if low > 0.0 and high / low > 10.0:
        return LogNorm(low, high)
    return Normalize(0.0 if high > 0.0 else -1.0, high if high > 0.0 else 1.0)


def plot_sweep(results: Mapping[tuple[str, float, float], CellResult], opts: SweepOptions, path: Path) -> Path:
    """Heatmaps (one panel per mode): x = one-way latency (ms), y = loss (%), colour = max tracking error (m)."""
    lats, losses = opts.latencies_ms, opts.losses_pct
    values = [r.max_tracking_error_m for r in results.values()
              if r.success and r.max_tracking_error_m is not None and r.cell.mode in opts.modes]
    norm, cmap = _colour_norm(values), colormaps["viridis"]
    panel_w, panel_h = max(4.0, 0.75 * len(lats) + 1.5), max(3.0, 0.55 * len(losses) + 1.8)
    fig = Figure(figsize=(panel_w * len(opts.modes) + 1.5, panel_h + 0.8), dpi=FIG_DPI, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, len(opts.modes), squeeze=False)[0]
    for ax, mode in zip(axes, opts.modes, strict=True):
        grid = np.full((len(losses), len(lats)), np.nan)
        for i, loss in enumerate(losses):
            for j, lat in enumerate(lats):
                r = results.get((mode, lat, loss))
                if r is not None and r.success and r.max_tracking_error_m is not None:
                    grid[i, j] = r.max_tracking_error_m
                _mark_cell(ax, j, i, r, norm, cmap)
        ax.pcolormesh(np.arange(len(lats) + 1) - 0.5, np.arange(len(losses) + 1) - 0.5, np.ma.masked_invalid(grid),
                      cmap=cmap, norm=norm)
        ax.set_xticks(range(len(lats)), labels=[_num(v) for v in lats])
        ax.set_yticks(range(len(losses)), labels=[_num(v) for v in losses])
        ax.set_xlim(-0.5, len(lats) - 0.5)
        ax.set_ylim(-0.5, len(losses) - 0.5)
        ax.set_xlabel("one-way latency, each direction (ms)")
        ax.set_ylabel("i.i.d. frame loss, each direction (%)")
        ax.set_title(f"{mode} mode")
    fig.colorbar(ScalarMappable(norm=norm, cmap=cmap), ax=list(axes), label="max tracking error (m)")
    fig.legend(handles=[Patch(facecolor="0.85", edgecolor="tab:red", hatch="xx", label="X: failed (no goal, "
                              "collision, crash or timeout)"),
                        Patch(facecolor="white", edgecolor="0.6", label="-: not flown")],
               loc="outside lower center", ncols=2, fontsize="small")
    world = Path(opts.world).name if opts.world else "empty room (hover)"
    fig.suptitle(f"Stability map: {world}\nbase radio '{opts.radio_base}', seed {opts.seed}, lockstep clock",
                 fontsize="medium")
    fig.savefig(path)
    return path


def _mark_cell(ax, x: int, y: int, result: CellResult | None, norm: Normalize, cmap) -> None:
    if result is None:
        ax.text(x, y, "-", ha="center", va="center", color="0.5")
    elif not result.success:
        ax.add_patch(Rectangle((x - 0.5, y - 0.5), 1.0, 1.0, facecolor="0.85", edgecolor="tab:red", hatch="xx",
                               linewidth=0.0, zorder=2))
        ax.text(x, y, "X", ha="center", va="center", color="tab:red", fontsize="x-large", fontweight="bold",
                zorder=3, bbox=dict(boxstyle="round", facecolor="white", edgecolor="none"))
    elif result.max_tracking_error_m is not None:
        value = result.max_tracking_error_m
        dark = norm(value) < 0.5  # viridis is dark at the low end
        ax.text(x, y, f"{value:.3f}", ha="center", va="center", fontsize="x-small", zorder=3,
                color="white" if dark else "black")
