"""states.csv's compiled row text (groundstation/_flightlog_kernel.c) is the Python twin's (flightlog._row_line),
number for number and row for row, and hands back to the Python the rows it would write differently (issue 19:
behaviour unchanged). Each number is Python's own "%.12g": checked against it on random doubles of every
magnitude and on the rounding boundaries the kernel's fast path has to tell apart."""

from __future__ import annotations

import math
import random
import struct
from decimal import Decimal

import numpy as np
import pytest

from groundstation import flightlog, flightlog_kernel
from groundstation.flightlog import FlightLog

needs_compiled = pytest.mark.skipif(
    not flightlog_kernel.COMPILED,
    reason="groundstation/_flightlog_kernel.c was not built (no C compiler at pip install): the log runs its Python")

BLOCKS = tuple(flightlog._BLOCKS.values())  # cells of truth, estimate, sigma, reference, moment_cmd, attitude_cmd


def _python(x: float) -> str:
    return flightlog.NUMBER % x


def _mismatches(values) -> list[tuple[float, str, str]]:
    texts = ((x, flightlog_kernel.format_number(x), _python(x)) for x in values)
    return [(x, kernel, python) for x, kernel, python in texts if kernel != python]


@needs_compiled
def test_numbers_of_every_bit_pattern_are_pythons():
    rng = random.Random(19)
    values = [struct.unpack("<d", struct.pack("<Q", rng.getrandbits(64)))[0] for _ in range(200_000)]
    assert _mismatches(values) == []


@needs_compiled
def test_numbers_of_every_magnitude_a_log_holds_are_pythons():
    """Decimal exponents from -20 to 40: the fast path's whole table (-16..38) and past both ends."""
    rng = random.Random(20)
    values = [rng.uniform(-10.0, 10.0) * 10.0 ** rng.randint(-20, 40) for _ in range(200_000)]
    assert _mismatches(values) == []


@needs_compiled
def test_numbers_on_and_beside_the_rounding_boundaries_are_pythons():
    """The double nearest each midpoint between two 12-digit decimals (where rounding to 12 digits is decided)
    and its neighbours either side; exact ties (small dyadic numbers: Python rounds them half to even); the
    powers of ten and their neighbours (where the exponent and the notation change)."""
    rng = random.Random(21)
    values = []
    for _ in range(60_000):
        digits, exponent = rng.randrange(10**11, 10**12), rng.randint(-18, 40)
        x = float(Decimal(2 * digits + 1) / 2 * Decimal(10) ** (exponent - 11))
        values += [x, math.nextafter(x, math.inf), math.nextafter(x, -math.inf), -x]
    values += [rng.randrange(1, 2**53) * 2.0 ** rng.randint(-60, 20) for _ in range(60_000)]
    values += [0.5, 2.5, 999999999999.5, 99999999999.95, 0.00012345678901250, 1.00000000000050]
    for exponent in range(-330, 309):
        p = float(f"1e{exponent}")
        values += [p, math.nextafter(p, math.inf), math.nextafter(p, -math.inf), -p, 9.999999999995 * p]
    assert _mismatches(values) == []


@needs_compiled
@pytest.mark.parametrize("x", [0.0, -0.0, math.inf, -math.inf, math.nan, -math.nan, 5e-324, -5e-324,
                               2.2250738585072014e-308, 1.7976931348623157e308, 1e-5, 1e-4, 1e11, 1e12])
def test_special_numbers_are_pythons(x):
    assert flightlog_kernel.format_number(x) == _python(x)


def _random_row(rng: random.Random) -> tuple:
    """FlightLog.row's 19 arguments as a flight passes them: floats, None for what is not known yet."""
    def number():
        return rng.choice([rng.uniform(-5, 5), rng.uniform(-1, 1) * 10.0 ** rng.randint(-12, 6), 0.0, -0.0])

    def maybe(value):
        return None if rng.random() < 0.2 else value

    blocks = [maybe(tuple(number() for _ in range(n))) for n in BLOCKS]
    if rng.random() < 0.3:  # lists as well as tuples
        blocks = [list(b) if b is not None else None for b in blocks]
    return (rng.uniform(0, 100), rng.choice(["connecting", "takeoff", "track", "land", "done"]), *blocks,
            maybe(rng.random() < 0.5), maybe(number()), maybe(rng.random() < 0.5), rng.randrange(0, 10**6),
            rng.randrange(0, 10**6), rng.randrange(0, 10**3), maybe(number()), maybe(number()), maybe(number()),
            maybe(number()), maybe(rng.uniform(3.0, 4.2)))


@needs_compiled
def test_rows_are_the_python_twins():
    rng = random.Random(22)
    for _ in range(20_000):
        row = _random_row(rng)
        assert flightlog_kernel.format_row(*row) == flightlog._row_line(*row), row


@needs_compiled
@pytest.mark.parametrize("slot, value", [
    (0, 3),                                   # an int time: "%.12g" % 3 is the Python's
    (1, "tâche"),                             # non-ASCII phase text
    (2, (1.0,) * 9),                          # a block one short: the Python raises
    (3, (1.0,) * 11),                         # one long
    (4, np.arange(9.0)),                      # an array, not a tuple or list
    (5, (1, 2.0, 3.0, 4.0, 5.0, 6.0)),        # an int in a block
    (6, iter([1.0, 2.0, 3.0, 4.0])),          # an iterator
    (8, np.bool_(True)),                      # a numpy bool
    (9, "1.0"),                               # text for a number: the Python raises
    (11, True),                               # a bool count: str(True) is "True"
    (12, 2**70),                              # beyond 64 bits
    (13, 7.0),                                # a float count
])
def test_what_the_kernel_does_not_take_is_left_to_the_python(slot, value):
    row = list(_random_row(random.Random(23)))
    row[slot] = value
    assert flightlog_kernel.format_row(*row) is None


def test_the_log_writes_the_same_file_with_and_without_the_kernel(tmp_path, monkeypatch):
    """FlightLog.row through the kernel, then with the kernel removed: the same bytes; and the rows the kernel
    hands back (an int time, a short block) are written, or refused, as the Python writes or refuses them."""
    rng = random.Random(24)
    rows = [_random_row(rng) for _ in range(2000)]
    rows[7] = (3, *rows[7][1:])
    written = {}
    for name, kernel in (("kernel", flightlog.format_row), ("python", None)):
        monkeypatch.setattr(flightlog, "format_row", kernel)
        with FlightLog(tmp_path / name) as log:
            for row in rows:
                log.row(*row)
            with pytest.raises(ValueError, match="expected 10 values, got 9"):
                log.row(*rows[0][:2], (1.0,) * 9, *rows[0][3:])
        written[name] = (tmp_path / name / "states.csv").read_bytes()
    assert written["kernel"] == written["python"]
    assert written["python"].count(b"\n") == len(rows) + 1  # the header and one line per row
