"""The sweep's grid: options, cells (every axis x seeds) and the radio profile of each cell.

Takes in: checked SweepOptions (groundstation.sweep.cli builds them) and base radio profiles (model.radio:
built-in names or TOML files; the ground station reads them as data, never through the simulator).
Gives out: the cells to fly, and per cell the text of its radio profile: the base with, where swept,
latency.base_s = L / 1000 s, latency.jitter_s = J / 1000 s, and the average loss P % either i.i.d.
(burst 1 frame) or in Gilbert-Elliott bursts of mean length B frames. Where only the loss is swept, B is
the base's own mean burst (1 for a base without bursts), so a bursty base stays bursty. The Crazyradio
model's per-attempt loss with retransmissions (profile `crazyradio`) is not part of P and comes on top.
The emulator applies the profile to both directions (uplink and downlink).
"""

from __future__ import annotations

import copy
import itertools
from dataclasses import astuple, dataclass, fields
from pathlib import Path

from model.config import Params, dump_toml
from model.radio import radio_profile_path

MODES = ("moments", "attitude")
DEFAULT_CELL_TIMEOUT_S = 600.0  # a lockstep flight of a lab maze takes ~10 s wall; this only catches hangs
MS_PER_S = 1000.0
PCT_PER_UNIT = 100.0
IID_BURST_FRAMES = 1.0  # a "burst" of one frame is i.i.d. loss


@dataclass(frozen=True)
class SweepOptions:
    worlds: tuple[str | None, ...]  # world JSON paths (None: fly's default empty room and hover)
    modes: tuple[str, ...]
    radios: tuple[str, ...]  # base radio profiles, names or TOML paths
    latencies_ms: tuple[float, ...] | None  # one-way; None: each base profile's own
    losses_pct: tuple[float, ...] | None  # average loss per frame and direction; None: the profile's
    jitters_ms: tuple[float, ...] | None = None  # latency jitter (the profile's law); None: the profile's
    bursts_frames: tuple[float, ...] | None = None  # mean loss-burst length; 1 = i.i.d.; None: the profile's
    controllers: tuple[str, ...] = ("",)  # fly --controller values; "" = the gains file's
    vehicle_draws: tuple[str, ...] = ("nominal",)
    seeds: tuple[int, ...] = (1,)
    jobs: int = 1
    out: Path = Path("sweep")
    extra: tuple[str, ...] = ()  # more `cfstack fly` arguments
    latency_compensation: bool | None = None  # None: fly's default
    timeout_s: float = DEFAULT_CELL_TIMEOUT_S
    resume: bool = False
    firmware: str = "crazyflie"  # the emulated vehicle's onboard side (fly --firmware)
    scheduler: str | None = None  # tcp://HOST:PORT of a running dask scheduler; None: a LocalCluster
    user_options: tuple[str, ...] = ()  # --trajectory/--planner/--controller-output for every flight

    def settings(self) -> dict:
        """What makes two sweeps' rows comparable (written to sweep.json, checked by --resume)."""
        return {"extra": list(self.extra), "latency_compensation": self.latency_compensation,
                "firmware": self.firmware}


def num(x: float) -> str:
    """A number as short as it reads ('10', '2.5'), exact on reading back."""
    short = f"{x:g}"
    return short if float(short) == x else repr(x)


@dataclass(frozen=True)
class Cell:
    """One flight: a value on every axis, and its seed."""

    world: str  # resolved path, "" for fly's empty room
    mode: str
    radio: str  # the base profile as given (name or path)
    latency_ms: float
    jitter_ms: float
    loss_pct: float
    burst_frames: float
    controller: str  # "" = the gains file's
    vehicle_draw: str
    seed: int

    @property
    def key(self) -> tuple:
        return astuple(self)

    @property
    def world_name(self) -> str:
        return Path(self.world).stem if self.world else "empty"

    @property
    def radio_name(self) -> str:
        return Path(self.radio).stem

    @property
    def slug(self) -> str:
        return (f"{self.world_name}_{self.mode}_{self.radio_name}_lat{num(self.latency_ms)}_jit{num(self.jitter_ms)}"
                f"_loss{num(self.loss_pct)}_burst{num(self.burst_frames)}_{self.controller_name}"
                f"_{Path(self.vehicle_draw).stem}_s{self.seed}")

    @property
    def label(self) -> str:
        return (f"{self.world_name} {self.mode} {self.radio_name} {num(self.latency_ms)} ms "
                f"+-{num(self.jitter_ms)} ms {num(self.loss_pct)} % burst {num(self.burst_frames)} "
                f"{self.controller_name} {self.vehicle_draw} seed {self.seed}")

    @property
    def controller_name(self) -> str:
        """The controller axis in names: the variant, 'gains', or a user file's stem and class."""
        if not self.controller:
            return "gains"
        path, _, name = self.controller.rpartition(":")
        return f"{Path(path).stem}-{name}" if path else self.controller

    @staticmethod
    def field_names() -> tuple[str, ...]:
        return tuple(f.name for f in fields(Cell))


def load_base_profile(name_or_path: str) -> Params:
    """A base profile, checked for what the sweep overrides (the emulator checks the rest)."""
    base = Params.load(radio_profile_path(name_or_path))
    latency = base.table("latency")
    latency.number("base_s", minimum=0.0)
    latency.number("jitter_s", minimum=0.0)
    base.table("loss").number("probability", minimum=0.0, maximum=1.0)
    burst = base.table("burst")
    burst.number("p_bad_to_good", minimum=0.0, maximum=1.0)
    burst.number("p_good_to_bad", minimum=0.0, maximum=1.0)
    base.string("name")
    base.string("source")
    return base


def _profile_burst_frames(data: dict) -> float:
    """The base profile's mean bad-state sojourn (frames), 1 when its bursts are off."""
    burst = data["burst"]
    enabled = burst["p_good_to_bad"] > 0.0 and burst["loss_bad"] > 0.0
    return 1.0 / burst["p_bad_to_good"] if enabled and burst["p_bad_to_good"] > 0.0 else IID_BURST_FRAMES


def _profile_loss_pct(data: dict) -> float:
    """The base profile's average loss per frame (%): i.i.d. plus its burst chain's stationary loss."""
    burst = data["burst"]
    gb, bg = burst["p_good_to_bad"], burst["p_bad_to_good"]
    pi_bad = gb / (gb + bg) if gb + bg > 0.0 else 0.0
    chain = pi_bad * burst["loss_bad"] + (1.0 - pi_bad) * burst["loss_good"]
    iid = data["loss"]["probability"]
    return PCT_PER_UNIT * (1.0 - (1.0 - iid) * (1.0 - chain))


def grid_cells(opts: SweepOptions, bases: dict[str, Params]) -> list[Cell]:
    """Every combination of the axes, seeds innermost; unswept radio axes take each base profile's values."""
    cells = []
    for world, mode, radio in itertools.product(opts.worlds, opts.modes, opts.radios):
        data = bases[radio].data
        latencies = opts.latencies_ms or (data["latency"]["base_s"] * MS_PER_S,)
        jitters = opts.jitters_ms or (data["latency"]["jitter_s"] * MS_PER_S,)
        losses = opts.losses_pct or (_profile_loss_pct(data),)
        bursts = opts.bursts_frames or (_profile_burst_frames(data),)
        for loss, latency, jitter, burst, controller, draw, seed in itertools.product(
                losses, latencies, jitters, bursts, opts.controllers, opts.vehicle_draws, opts.seeds):
            cells.append(Cell(str(Path(world).resolve()) if world else "", mode, radio, latency, jitter, loss, burst,
                              controller, draw, seed))
    return cells


def _apply_loss(data: dict, loss_pct: float, burst_frames: float) -> None:
    """Average loss P % per frame: i.i.d. for a burst of 1 frame, else a Gilbert-Elliott chain whose bad state
    loses every frame and lasts B frames on average (p_bg = 1 / B), entered so that it holds a fraction P of
    the frames (pi_bad = p_gb / (p_gb + p_bg) = P)."""
    p = loss_pct / PCT_PER_UNIT
    burst = data["burst"]
    if burst_frames == IID_BURST_FRAMES or p == 0.0 or p >= 1.0:
        data["loss"]["probability"] = p
        burst.update(p_good_to_bad=0.0, p_bad_to_good=1.0, loss_good=0.0, loss_bad=0.0)
        return
    p_bg = 1.0 / burst_frames
    data["loss"]["probability"] = 0.0
    burst.update(p_good_to_bad=min(1.0, p * p_bg / (1.0 - p)), p_bad_to_good=p_bg,
                 loss_good=0.0, loss_bad=1.0)


def cell_profile(base: Params, cell: Cell, opts: SweepOptions) -> dict:
    """The base profile's data with the swept radio axes of this cell applied."""
    data = copy.deepcopy(base.data)
    base_name = data["name"]
    changes = []
    if opts.latencies_ms is not None:
        data["latency"]["base_s"] = cell.latency_ms / MS_PER_S
        changes.append(f"latency.base_s = {num(cell.latency_ms)} ms")
    if opts.jitters_ms is not None:
        data["latency"]["jitter_s"] = cell.jitter_ms / MS_PER_S
        changes.append(f"latency.jitter_s = {num(cell.jitter_ms)} ms ({data['latency']['jitter']})")
    if opts.losses_pct is not None or opts.bursts_frames is not None:
        _apply_loss(data, cell.loss_pct, cell.burst_frames)
        changes.append(f"average loss {num(cell.loss_pct)} % per frame, "
                       + ("i.i.d." if cell.burst_frames == IID_BURST_FRAMES or cell.loss_pct == 0.0
                          else f"in Gilbert-Elliott bursts of mean {num(cell.burst_frames)} frames"))
    data["name"] = f"{base_name}_lat{num(cell.latency_ms)}_jit{num(cell.jitter_ms)}_loss{num(cell.loss_pct)}" \
                   f"_burst{num(cell.burst_frames)}"
    data["source"] = (f"Generated by cfstack sweep from '{base_name}' ({base.source}): "
                      f"{'; '.join(changes) or 'unchanged'} (both directions); everything else as in the base, "
                      f"whose source is: {data['source']}")
    return data


def cell_profile_text(base: Params, cell: Cell, opts: SweepOptions) -> str:
    return dump_toml(cell_profile(base, cell, opts), header="Generated by `cfstack sweep` for one cell.")
