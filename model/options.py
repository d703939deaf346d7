"""Command-line option types every `cfstack` subcommand shares, so a value means the same everywhere.

Takes in: the text of one option value.
Gives out: the checked value, or argparse.ArgumentTypeError with one line saying what is wrong (which
model.errors.OneLineParser turns into `cfstack CMD: argument --X: ...` and exit code 2). NaN and
infinity are never accepted where a finite number is meant.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a number") from None


def finite_float(text: str) -> float:
    value = _number(text)
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text} is not a finite number")
    return value


def positive_float(text: str) -> float:
    value = finite_float(text)
    if value <= 0.0:
        raise argparse.ArgumentTypeError(f"{text} must be a positive number")
    return value


def non_negative_float(text: str) -> float:
    value = finite_float(text)
    if value < 0.0:
        raise argparse.ArgumentTypeError(f"{text} must be a number >= 0")
    return value


def float_in(low: float, high: float, unit: str = "") -> Callable[[str], float]:
    """A finite number in (low, high]: e.g. a control rate above 0 Hz and at most the firmware's rate."""
    def parse(text: str) -> float:
        value = finite_float(text)
        if not low < value <= high:
            raise argparse.ArgumentTypeError(f"{text} is outside ({low:g}, {high:g}]{' ' + unit if unit else ''}")
        return value

    return parse


def whole_number(minimum: int, meaning: str, maximum: int | None = None) -> Callable[[str], int]:
    """A whole number >= minimum (and <= maximum); `meaning` says what the value is, for the message."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"'{text}' is not a whole number") from None
        if value < minimum or (maximum is not None and value > maximum):
            span = f"{minimum}..{maximum}" if maximum is not None else f"{minimum} or more"
            raise argparse.ArgumentTypeError(f"{value} is not {meaning} ({span})")
        return value

    return parse


seed = whole_number(0, "a seed")
