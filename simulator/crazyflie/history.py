"""The estimator's recent past, to meet a late measurement (an external pose) at its own sample time.

Takes in: (sample time s, value) pairs in time order, one per estimator update.
Gives out: the value at or just before a given time (the oldest kept when the time is older still; None
when nothing is kept). Keeps the last `length` pairs (1 s at 250 Hz by default: above any latency modelled).
"""

from __future__ import annotations

import bisect
from collections import deque

DEFAULT_LENGTH = 250


class TimeHistory:
    def __init__(self, length: int = DEFAULT_LENGTH):
        self._times: deque[float] = deque(maxlen=length)
        self._values: deque = deque(maxlen=length)

    def append(self, time_s: float, value) -> None:
        self._times.append(time_s)
        self._values.append(value)

    def at(self, time_s: float):
        if not self._values:
            return None
        i = bisect.bisect_right(self._times, time_s) - 1
        return self._values[max(i, 0)]
