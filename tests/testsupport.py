"""What many tests share: where the course's world files are, and free loopback ports.

Takes in: nothing (the shared worlds are looked for at ../shared/worlds beside the checkout, where CI
puts them).
Gives out: SHARED_WORLDS, `shared_world(name)` (the file, or a visible skip saying why it is absent),
`shared_world_params(*patterns)` (pytest parameters over the matching files, or one skipped parameter
naming the missing folder, so the cases never vanish silently), `free_port(kind)` (the product's
link.transports.base.free_loopback_port) and `cfstack(*args)` (the command as a user runs it: a
subprocess, output captured, no stdin, a timeout).
Importable from every test module (pyproject.toml: pytest pythonpath = ["tests"]).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from link.transports.base import free_loopback_port as free_port  # noqa: F401 (one helper, re-exported)

SHARED_WORLDS = Path(__file__).resolve().parents[1].parent / "shared" / "worlds"
ABSENT_REASON = f"the course's world files are not at {SHARED_WORLDS} (../shared/worlds beside the checkout)"


def shared_worlds_present() -> bool:
    return SHARED_WORLDS.is_dir()


def shared_world(name: str) -> Path:
    """The path of ../shared/worlds/NAME.json; skips the calling test, saying why, when it is absent."""
    path = SHARED_WORLDS / f"{name}.json"
    if not path.is_file():
        pytest.skip(ABSENT_REASON if not shared_worlds_present() else f"{path} is missing")
    return path


def shared_world_params(*patterns: str) -> list:
    """pytest parameters: the stems of the shared world files matching the glob patterns, in order; one
    skipped parameter with the reason when the folder is absent."""
    if not shared_worlds_present():
        return [pytest.param("absent", marks=pytest.mark.skip(reason=ABSENT_REASON), id="shared-worlds-absent")]
    stems: list[str] = []
    for pattern in patterns:
        stems += sorted(p.stem for p in SHARED_WORLDS.glob(pattern) if p.stem not in stems)
    return stems


def cfstack(*args: str, timeout: float = 240, **kw) -> subprocess.CompletedProcess:
    """`python -m cfstack ARGS` as a user runs it; stdout and stderr captured as text."""
    return subprocess.run([sys.executable, "-m", "cfstack", *args], capture_output=True, text=True,
                          timeout=timeout, stdin=subprocess.DEVNULL, **kw)
