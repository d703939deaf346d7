"""Reading (and writing) versioned TOML parameter files, with one-line errors naming the file and the field.

Takes in: a TOML file path, or a built-in name looked up in a package's params folder.
Gives out: a `Params` view whose accessors check type, range and presence, raising ConfigError
("FILE: field: problem"); `dump_toml`, the one TOML writer (tomllib only reads), for generated files
such as the radio profiles of a sweep.
"""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Mapping
from importlib import resources
from pathlib import Path

from model.errors import ConfigError

SUPPORTED_SCHEMA = 1


def builtin_path(package: str, folder: str, name: str) -> Path:
    """Path of a shipped parameter file, e.g. builtin_path("model", "params/vehicles", "crazyflie")."""
    return Path(str(resources.files(package).joinpath(folder, f"{name}.toml")))


def builtin_names(package: str, folder: str) -> list[str]:
    base = resources.files(package).joinpath(folder)
    return sorted(p.name[:-5] for p in base.iterdir() if p.name.endswith(".toml"))


def resolve(name_or_path: str | Path, package: str, folder: str, what: str) -> Path:
    """A file path as given, or the built-in file of that name; a clear error if neither exists."""
    candidate = Path(name_or_path)
    # A path is what looks like one (a .toml suffix or a folder part); a bare word is a built-in name,
    # even if a file of that name happens to sit in the current folder.
    if candidate.suffix == ".toml" or len(candidate.parts) > 1:
        if not candidate.is_file():
            raise ConfigError(f"{candidate}: {what} file not found")
        return candidate
    path = builtin_path(package, folder, str(name_or_path))
    if not path.is_file():
        known = ", ".join(builtin_names(package, folder))
        raise ConfigError(f"unknown {what} '{name_or_path}' (built-in: {known}; or give a .toml file)")
    return path


class Params:
    """A checked view of one TOML table."""

    def __init__(self, data: dict, source: str, prefix: str = ""):
        self.data = data
        self.source = source
        self.prefix = prefix

    @staticmethod
    def load(path: str | Path) -> Params:
        path = Path(path)
        try:
            data = tomllib.loads(path.read_text())
        except OSError as err:
            raise ConfigError(f"{path}: cannot read ({err.strerror})") from None
        except tomllib.TOMLDecodeError as err:
            raise ConfigError(f"{path}: not valid TOML ({err})") from None
        params = Params(data, str(path))
        version = params.integer("schema_version")
        if version != SUPPORTED_SCHEMA:
            raise params.error("schema_version", f"unsupported version {version} (expected {SUPPORTED_SCHEMA})")
        return params

    def error(self, key: str, problem: str) -> ConfigError:
        return ConfigError(f"{self.source}: {self.prefix}{key}: {problem}")

    def has(self, key: str) -> bool:
        return key in self.data

    def _get(self, key: str):
        if key not in self.data:
            raise self.error(key, "missing")
        return self.data[key]

    def table(self, key: str) -> Params:
        value = self._get(key)
        if not isinstance(value, dict):
            raise self.error(key, "expected a table")
        return Params(value, self.source, f"{self.prefix}{key}.")

    def number(self, key: str, minimum: float | None = None, maximum: float | None = None,
               default: float | None = None) -> float:
        if default is not None and key not in self.data:
            return float(default)
        value = self._get(key)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.error(key, f"expected a finite number, got {value!r}")
        if minimum is not None and value < minimum:
            raise self.error(key, f"{value} is below the minimum {minimum}")
        if maximum is not None and value > maximum:
            raise self.error(key, f"{value} is above the maximum {maximum}")
        return float(value)

    def integer(self, key: str, minimum: int | None = None, default: int | None = None) -> int:
        if default is not None and key not in self.data:
            return default
        value = self._get(key)
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(key, f"expected an integer, got {value!r}")
        if minimum is not None and value < minimum:
            raise self.error(key, f"{value} is below the minimum {minimum}")
        return value

    def string(self, key: str, choices: tuple[str, ...] | None = None, default: str | None = None) -> str:
        if default is not None and key not in self.data:
            return default
        value = self._get(key)
        if not isinstance(value, str):
            raise self.error(key, f"expected a string, got {value!r}")
        if choices is not None and value not in choices:
            raise self.error(key, f"'{value}' is not one of {', '.join(choices)}")
        return value

    def vector(self, key: str, length: int, default: list[float] | None = None) -> list[float]:
        if default is not None and key not in self.data:
            return list(default)
        value = self._get(key)
        if not isinstance(value, list) or len(value) != length:
            raise self.error(key, f"expected a list of {length} numbers")
        out = []
        for i, v in enumerate(value):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise self.error(f"{key}[{i}]", f"expected a finite number, got {v!r}")
            out.append(float(v))
        return out

    def matrix(self, key: str, rows: int, cols: int) -> list[list[float]]:
        value = self._get(key)
        if not isinstance(value, list) or len(value) != rows:
            raise self.error(key, f"expected {rows} rows of {cols} numbers")
        return [Params({"row": row}, self.source, f"{self.prefix}{key}[{i}].").vector("row", cols)
                for i, row in enumerate(value)]


def _toml_value(value, where: str) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ConfigError(f"{where}: cannot write {value!r}")
        return repr(value)  # shortest round-trip form, valid TOML ("1e-05", "0.02")
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)  # JSON string escapes are valid TOML basic strings
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v, where) for v in value) + "]"
    raise ConfigError(f"{where}: cannot write a {type(value).__name__} value to TOML")


def dump_toml(data: Mapping, header: str = "") -> str:
    """TOML text of nested tables of scalars and lists (what radio profiles hold)."""
    lines = [f"# {line}" for line in header.splitlines()]

    def emit(table: Mapping, prefix: str) -> None:
        for key, value in table.items():
            if not isinstance(value, Mapping):
                lines.append(f"{key} = {_toml_value(value, prefix + key)}")
        for key, value in table.items():
            if isinstance(value, Mapping):
                lines.extend(["", f"[{prefix}{key}]"])
                emit(value, f"{prefix}{key}.")

    emit(data, "")
    return "\n".join(lines) + "\n"
