"""What the flight tests that run `cfstack` programs share: radio profile files derived from the shipped
`ideal` profile (fixed latency, i.i.d. and bursty loss). Imported by tests in this folder (sys.path), like
trajectory_checks and reference_paths."""

from __future__ import annotations

import tomllib
from pathlib import Path

from model.config import dump_toml

RADIO_DIR = Path(__file__).resolve().parents[2] / "model" / "params" / "radio"


def radio_profile(folder: Path, name: str, latency_s: float = 0.0, loss: float = 0.0,
                  burst: tuple[float, float, float, float] = (0.0, 1.0, 0.0, 0.0)) -> Path:
    """A radio profile file `folder/name.toml`: the ideal profile's layout with a fixed one-way latency
    (no jitter), i.i.d. loss, and (p_good_to_bad, p_bad_to_good, loss_good, loss_bad) bursts."""
    p_gb, p_bg, loss_good, loss_bad = burst
    data = tomllib.loads((RADIO_DIR / "ideal.toml").read_text())
    data["name"] = name
    data["source"] = "test profile"
    data["latency"].update(base_s=latency_s, jitter_s=0.0)
    data["loss"]["probability"] = loss
    data["burst"].update(p_good_to_bad=p_gb, p_bad_to_good=p_bg, loss_good=loss_good, loss_bad=loss_bad)
    path = folder / f"{name}.toml"
    path.write_text(dump_toml(data))
    return path

