"""states.csv's row formatting, compiled (issue 19): the text of FlightLog.row's line.

Takes in: FlightLog.row's arguments, in its order.
Gives out: `format_row`, the compiled kernel (groundstation/_flightlog_kernel.c, built by `pip install`), or None
where it was not built; it returns the row's line, or None for a row it leaves to its Python twin,
flightlog._row_line (any value not of the types FlightLog.row documents, a block of the wrong length); and
`format_number`, the kernel's "%.12g" of one float (for the tests).

Same text as the Python (tests/groundstation/test_flightlog_kernel.py). Why compiled: the row is written every
tick, after the ack but on the flight loop's thread, whose CPU time per tick bounds a lockstep flight's speed (a
flight whose row was a constant line flew 1.18x faster, 8 pairs); Python's "%.12g" of its numbers (up to 50), the
cells' strings and their join took 27 us of CPU per row in a moments circle (13 us in a warm replay of its rows).
"""

from __future__ import annotations

try:
    from groundstation._flightlog_kernel import format_number, format_row
except ImportError:  # not built (no C compiler at install): the log runs its Python, same text, slower
    format_row = format_number = None

COMPILED = format_row is not None
