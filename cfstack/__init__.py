"""cfstack: the application layer over the packages, what a user runs.

Holds: the `cfstack` command's dispatcher (cfstack.cli, subcommands listed in pyproject.toml's
`cfstack.commands` entry points), `cfstack link-bench` (cfstack.link_bench) and the Python API
(`cfstack.fly`, cfstack.api).
Takes in: command lines, or the API's arguments.
Gives out: the subcommands' results and exit codes; the API's Flight.
May import every package (groundstation, simulator, estimator, link, model), but only when a subcommand
that needs one runs; no package imports cfstack.
"""


def fly(world=None, **kwargs):
    """Fly once from Python, as `cfstack fly` does (cfstack.api.fly: arguments and result)."""
    from cfstack.api import fly as api_fly

    return api_fly(world, **kwargs)
