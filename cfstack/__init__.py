"""cfstack: the application layer over the packages, what a user runs.

Holds: the `cfstack` command's dispatcher (cfstack.cli, subcommands listed in pyproject.toml's
`cfstack.commands` entry points) and `cfstack link-bench` (cfstack.link_bench).
Takes in: command lines.
Gives out: the subcommands' results and exit codes.
May import every package (groundstation, simulator, estimator, link, model), but only when a subcommand
that needs one runs; no package imports cfstack.
"""
