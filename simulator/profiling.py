"""Per-part wall-time accounting for benchmarks, without a second copy of any step path.

Takes in: an object, the names of methods to time, and the part each one's time counts towards.
Gives out: the object with those methods replaced, on the instance only, by wrappers that add their
time.perf_counter duration to timing[part]. The code that calls them is the same with or without
profiling, and an object never profiled pays nothing (the methods are looked up as before).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping


def timed(fn: Callable, timing: dict[str, float], part: str) -> Callable:
    """fn, adding each call's wall time (s) to timing[part]."""
    clock = time.perf_counter

    def wrapper(*args, **kwargs):
        start = clock()
        try:
            return fn(*args, **kwargs)
        finally:
            timing[part] += clock() - start

    return wrapper


def time_parts(obj: object, parts: Mapping[str, str], timing: dict[str, float]) -> None:
    """Time obj's methods: parts maps a method name to the part its time counts towards."""
    for name, part in parts.items():
        timing.setdefault(part, 0.0)
        setattr(obj, name, timed(getattr(obj, name), timing, part))
