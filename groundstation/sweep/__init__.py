"""`cfstack sweep`: stability maps and Monte Carlo, one mission flown over a grid of axes x seeds, each
flight a task on dask.distributed.

Modules: grid (options, cells, each cell's radio profile), cell_task (one flight, where a worker runs it),
runner (the dask client: LocalCluster or --scheduler, retries, lost workers), table (sweep.csv and
sweep.parquet, aggregates over seeds, what they say), plot (sweep.png), cli (the command).

Takes in: `cfstack sweep [WORLD ...] [--mode M ...] [--radio BASE ...] [--latency MS,...] [--jitter MS,...]
[--loss PCT,...] [--burst FRAMES,...] [--controller V ...] [--vehicle-draw P ...] [--seed N] [--seeds N]
[--jobs N | --scheduler tcp://HOST:PORT] [--out DIR] [--extra "ARGS"] [--timeout S] [--resume]`.
Gives out, in OUT (default ./sweep): sweep.csv and sweep.parquet (one row per flight, rewritten atomically
as each finishes), sweep.json (the settings --resume checks), sweep.png (success rate over seeds and the
spread of the tracking error per latency x loss cell), cells/<flight>/ (each flight's logs, on its
worker's machine); on stdout a table per panel and the largest latency survived at 0 % and 20 % loss; a
progress bar on stderr (done, failed, retried, lost workers, ETA, dashboard address). Exit code 0 when every
flight was flown, 130 after Ctrl-C (rerun with --resume), 2 for bad input.

May import: groundstation (controller variants, preflight), model; never the simulator (workers start
`cfstack fly`, which starts the emulator as a process).
"""

from groundstation.sweep.cli import command

__all__ = ["command"]
