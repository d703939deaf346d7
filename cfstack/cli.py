"""The `cfstack` command: a dispatcher over the subcommands each package registers.

Takes in: `cfstack SUBCOMMAND [ARGS...]`.
Gives out: runs the subcommand's `command(argv) -> int`; a UserError becomes one line on stderr and its
exit code (2), Ctrl-C exit code 130; never a traceback for bad input.

The subcommand table is the `cfstack.commands` entry-point group in pyproject.toml, so this module
never imports the ground station or the emulator until the user names them.
"""

from __future__ import annotations

import sys
from importlib.metadata import entry_points

from model.errors import UserError


def _commands() -> dict:
    return {ep.name: ep for ep in entry_points(group="cfstack.commands")}


def _usage(commands: dict) -> str:
    lines = ["usage: cfstack SUBCOMMAND [ARGS...]", "", "subcommands:"]
    for name in sorted(commands):
        lines.append(f"  {name}")
    lines.append("")
    lines.append("Run 'cfstack SUBCOMMAND --help' for its options.")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    commands = _commands()
    if not argv or argv[0] in ("-h", "--help"):
        print(_usage(commands))
        return 0 if argv else 2
    name, rest = argv[0], argv[1:]
    if name not in commands:
        print(f"cfstack: unknown subcommand '{name}' (one of: {', '.join(sorted(commands))})", file=sys.stderr)
        return 2
    try:
        return int(commands[name].load()(rest) or 0)
    except UserError as err:
        print(f"cfstack {name}: {err}", file=sys.stderr)
        return err.exit_code
    except KeyboardInterrupt:
        print(f"cfstack {name}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 1


if __name__ == "__main__":
    sys.exit(main())
