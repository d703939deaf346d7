"""Errors a user can cause (bad files, bad arguments, impossible requests).

Takes in: a one-line message naming the file or field.
Gives out: an exception the `cfstack` dispatcher prints as one line with a non-zero exit code,
never a traceback; OneLineParser, the argparse every subcommand uses, which reports a bad option that way
(not as a usage block and SystemExit).
"""

import argparse


class UserError(Exception):
    """A problem with the user's input. `str(err)` is the whole one-line message."""

    exit_code = 2


class ConfigError(UserError):
    """A parameter (TOML) file is missing, malformed, or has a wrong or missing field."""


class WorldError(UserError):
    """A world (JSON) file is malformed or describes an impossible world."""


class OneLineParser(argparse.ArgumentParser):
    """argparse whose bad option is a one-line UserError (exit code 2), naming the option and pointing
    at --help, instead of a usage block and SystemExit."""

    def error(self, message: str):
        raise UserError(f"{message} (see '{self.prog} --help')")
