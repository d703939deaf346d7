"""The Python API for notebooks and scripts: `cfstack.fly(...)`, what `cfstack fly` does.

Takes in: a world (JSON path, or None for an empty room), the user's controller/trajectory/planner as
classes and functions or as PATH[:Name] strings, and any `cfstack fly` option as a keyword (underscores
for dashes: rate=100, firmware="ideal", latency_compensation=False; True for a bare flag).
Gives out: a Flight (the summary dict the CLI prints with --json, the log folder, the per-tick record).
`cfstack fly` is this same path: both parse into the fly command's options and call
groundstation.cli.fly, so the API can do nothing the command cannot, and the other way round.
Bad input raises model.errors.UserError with the CLI's one-line message.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Flight:
    summary: dict  # as summary.json and `cfstack fly --json`
    log_dir: Path
    record: object  # groundstation.flight.FlightRecord: per-tick reference, estimate and truth

    @property
    def reached_goal(self) -> bool:
        return bool(self.summary["reached_goal"]) and not self.summary["collided"]


def fly(world: str | Path | None = None, *, controller=None, trajectory=None, planner=None,
        mode: str = "moments", radio: str | None = None, clock: str = "lockstep", seed: int = 1,
        log: str | Path | None = None, **options) -> Flight:
    """Fly once, as `cfstack fly` does; see the module docstring for the arguments."""
    from groundstation import cli

    objects = {}
    argv = [str(world)] if world is not None else []
    for kind, value in (("controller", controller), ("trajectory", trajectory), ("planner", planner)):
        if isinstance(value, str | Path):
            argv += [f"--{kind}", str(value)]
        elif value is not None:
            objects[kind] = value
    argv += ["--mode", mode, "--clock", clock, "--seed", str(seed)] + (["--radio", radio] if radio else [])
    if log is not None:
        argv += ["--log", str(log)]
    argv += _option_words(options)
    args = cli._parsed(cli.fly_parser(), argv)  # the command's own parser and checks
    result = cli.fly(args, objects)
    return Flight(result.summary, Path(result.summary["log_dir"]), result.record)


def _option_words(options: dict) -> list[str]:
    words: list[str] = []
    for key, value in options.items():
        flag = "--" + key.replace("_", "-")
        if value is True:
            words.append(flag)
        elif value is False:
            words.append("--no-" + key.replace("_", "-"))
        elif isinstance(value, list | tuple):
            words += [flag, *(str(v) for v in value)]
        elif value is not None:
            words += [flag, str(value)]
    return words
