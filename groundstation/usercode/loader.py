"""Load a user's course-style file unchanged: `PATH[:Name]` to a class or function.

Takes in: a spec `PATH[:Name]` (PATH a .py file, or a directory holding the course's file name for the
kind: se3_control.py, world_traj.py, graph_search.py) and the kind (controller, trajectory, planner).
Gives out: the named object, imported as `proj1_3.code.<module>` with the course's import environment:
- a `flightsim` package (groundstation/usercode/compat/flightsim) first on sys.path;
- the file's directory mounted as the package `proj1_3.code`, followed by compat/course_code (the course's
  occupancy_map and graph_search, for a directory that lacks them), so `from proj1_3.code.x import y`
  and `from .x import y` both resolve;
- the file's directory and then compat/course_code on sys.path, for flat `from x import y`.
A missing file, a file that fails to import or a missing name is one UserError line naming the file.
"""

from __future__ import annotations

import importlib
import importlib.machinery
import importlib.util
import sys
import traceback
import types
from dataclasses import dataclass
from pathlib import Path

import groundstation.usercode.compat as compat
from model.errors import UserError

COURSE_PACKAGE = "proj1_3.code"  # the course harness's default target (util/test.py set_target)
DEFAULTS = {  # kind: (course file name, object name)
    "controller": ("se3_control.py", "SE3Control"),
    "trajectory": ("world_traj.py", "WorldTraj"),
    "planner": ("graph_search.py", "graph_search"),
}
COMPAT_ROOT = Path(compat.__file__).parent
COURSE_CODE = COMPAT_ROOT / "course_code"


@dataclass(frozen=True)
class UserObject:
    """A loaded class or function and where it came from (for error lines)."""

    obj: object
    file: Path
    name: str
    kind: str

    @property
    def label(self) -> str:
        return f"{self.file.name} {self.name}"


def looks_like_path(value: str) -> bool:
    """A --controller/--trajectory value that names user code rather than a built-in choice."""
    return value.endswith(".py") or "/" in value or ".py:" in value or Path(value).is_dir()


def builtin_or_user_file(value: str | None, choices: tuple[str, ...], kind: str) -> tuple[str | None, str | None]:
    """(built-in choice, user spec) of an option that takes either: a --controller report|full|PATH or a
    --trajectory hover|...|PATH. Neither a choice nor a path is one UserError line."""
    if value is None or value in choices:
        return value, None
    if looks_like_path(value):
        return None, value
    raise UserError(f"argument --{kind}: {value}: one of {', '.join(choices)} or a user {kind} file PATH[:Class]")


def split_spec(spec: str, kind: str) -> tuple[Path, str]:
    """(file, object name) of `PATH[:Name]`; PATH may be a directory holding the course's file."""
    default_file, default_name = DEFAULTS[kind]
    path_text, name = spec, default_name
    head, sep, tail = spec.rpartition(":")
    if sep and tail.isidentifier() and head:
        path_text, name = head, tail
    path = Path(path_text).expanduser()
    if path.is_dir():
        path = path / default_file
    if not path.is_file():
        raise UserError(f"--{kind} {spec}: no such file {path}")
    if path.suffix != ".py" or not path.stem.isidentifier():
        raise UserError(f"--{kind} {spec}: {path} is not an importable Python file (name.py)")
    return path.resolve(), name


def load(spec: str, kind: str) -> UserObject:
    """The object `spec` names, imported with the course's import environment (module docstring)."""
    path, name = split_spec(spec, kind)
    mount(path.parent)
    try:
        module = _import_file(f"{COURSE_PACKAGE}.{path.stem}", path)
    except Exception as err:  # noqa: BLE001 - any failure of the user's module is one line
        raise UserError(f"--{kind} {path}: importing it failed: {describe_error(err, path.parent)}") from None
    obj = getattr(module, name, None)
    if obj is None:
        raise UserError(f"--{kind} {path}: has no {name} (give PATH:Name for another name)")
    if not callable(obj):
        raise UserError(f"--{kind} {path}: {name} is not a class or function")
    return UserObject(obj, path, name, kind)


def _import_file(module_name: str, path: Path) -> types.ModuleType:
    """`path` as `module_name`, from that very file: two users' files of one name (a controller and a
    planner from different folders) must each be the one loaded, whatever was imported before."""
    module = sys.modules.get(module_name)
    if module is not None and Path(getattr(module, "__file__", "") or "").resolve() == path:
        return module
    spec = importlib.util.spec_from_file_location(module_name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[module_name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        sys.modules.pop(module_name, None)
        raise
    return module


def mount(directory: Path) -> None:
    """Make the course's imports resolve for files in `directory`, and for nothing else: the modules a
    previously mounted folder imported are forgotten first, so one student's `graph_search` is never
    another's (objects already loaded keep their own modules)."""
    directory = Path(directory).resolve()
    _forget_user_modules()
    _put_on_path(str(COMPAT_ROOT), front=True)
    for old in _mounted:
        if old in sys.path:
            sys.path.remove(old)
    _mounted[:] = [str(directory)]
    sys.path.insert(0, str(directory))
    _put_on_path(str(COURSE_CODE), front=False)
    outer = sys.modules.get("proj1_3") or _package("proj1_3", [])
    code = sys.modules.get(COURSE_PACKAGE) or _package(COURSE_PACKAGE, [])
    outer.code = code
    code.__path__[:] = [str(directory), str(COURSE_CODE)]  # its own files first, then the course's helpers
    importlib.invalidate_caches()


_mounted: list[str] = []  # the user folder currently on sys.path


def _forget_user_modules() -> None:
    """Drop `proj1_3.code.*` and flat-imported modules loaded from a user folder or compat/course_code."""
    folders = {Path(d) for d in _mounted} | {COURSE_CODE}
    for name, module in list(sys.modules.items()):
        file = getattr(module, "__file__", None)
        flat = "." not in name and file is not None and Path(file).resolve().parent in folders
        if name.startswith(COURSE_PACKAGE + ".") or flat:
            del sys.modules[name]


def _package(name: str, locations: list[str]) -> types.ModuleType:
    spec = importlib.machinery.ModuleSpec(name, None, is_package=True)
    spec.submodule_search_locations = locations
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    return module


def _put_on_path(entry: str, front: bool) -> None:
    if entry in sys.path:
        return
    sys.path.insert(0, entry) if front else sys.path.append(entry)


def describe_error(err: BaseException, directories) -> str:
    """`Type: message (file:line)` at the deepest frame in one of the user's directories, else the error
    alone. directories: a Path or several."""
    dirs = {Path(d).resolve() for d in ([directories] if isinstance(directories, (str, Path)) else directories)}
    frames = [f for f in traceback.extract_tb(err.__traceback__) if Path(f.filename).resolve().parent in dirs]
    at = f" ({Path(frames[-1].filename).name}:{frames[-1].lineno})" if frames else ""
    if isinstance(err, SyntaxError) and err.lineno:
        at = f" ({Path(err.filename or '?').name}:{err.lineno})"
    message = str(err).splitlines()[0] if str(err) else ""
    return f"{type(err).__name__}: {message}{at}"
