"""`cfstack sweep`: the stability map, one mission flown over a grid of radio latency x loss per mode.

Modules: grid (options, cells, cell radio profiles), runner (the flights), table (sweep.csv and what it
says), plot (sweep.png), cli (the command).

Takes in: `cfstack sweep [WORLD] --mode moments|attitude [--mode ...] --latency MS,... --loss PCT,...
[--jobs N] [--out DIR] [--seed N] [--radio BASE] [--extra "ARGS"] [--latency-compensation] [--timeout S]
[--resume]`.
Gives out, in OUT (default ./sweep):
  profiles/*.toml  one radio profile per (latency, loss): the base profile (default `ideal`, no other
                   impairment) with latency.base_s = L / 1000 s and i.i.d. loss.probability = P / 100;
                   the emulator applies the one profile to both directions (uplink and downlink);
  cells/<cell>/    each flight's log folder (`cfstack fly --log`), plus fly_stdout.json / fly_stderr.txt;
  sweep.csv        one row per cell (CSV_COLUMNS; `reason` is fly's failsafe_reason, or the last line fly
                   wrote on stderr when it crashed or timed out), rewritten after every finished cell;
  sweep.json       the settings the cells were flown with (what --resume checks);
  sweep.png        heatmaps, one panel per mode: latency x loss, colour = max tracking error (m),
                   failed cells hatched and marked X;
and on stdout a table per mode and, per mode, the largest one-way latency it survives at 0 % and 20 % loss.
A progress bar (cells done / total, elapsed, ETA) goes to stderr.

Every cell is `cfstack fly WORLD --mode M --radio PROFILE --clock lockstep --seed N --json --log DIR`
in its own subprocess (lockstep + seed: the same cell gives the same flight on a busy machine), at
most --jobs at a time. A cell whose fly exits with code 2 (bad input) aborts the sweep with fly's
one-line error; a crash, a timeout or a failsafe is a normal, failed cell. Ctrl-C stops the running
flights and still writes what was done (exit code 130); `--resume` skips the cells already in sweep.csv.

"Survives" is conservative: success (goal reached, no collision) in that cell AND in every cell of
lower latency at the same loss, so a lucky cell past a failure does not count.
"""

from groundstation.sweep.cli import command

__all__ = ["command"]
