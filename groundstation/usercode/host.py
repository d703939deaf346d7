"""Everything a session needs to fly a user's course-style code: load, construct, attach, report.

Takes in: what the user named (PATH[:Name] strings from the command line, or classes and functions from
the Python API), the vehicle model, the world, the controller output choice.
Gives out: a UserCode with
- the constructed controller (SE3Control(quad_params), quad_params the course's 9 keys for the vehicle in
  use) and the built trajectory (WorldTraj(world, start, goal), built before any flight clock runs, with a
  progress line every few seconds), both constructed before the emulator starts;
- the planner for cfstack's own trajectories (groundstation.planned);
- controller_for(...) and attach(mission): the adapters wired to the mission's failsafe;
- summary(): the user's own time per call (p50/p99/max), overruns, notes, the fault line if any.
Bad user code before the flight (import, constructor) is one UserError line naming file and method.
"""

from __future__ import annotations

import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from groundstation.controller import SE3Controller
from groundstation.usercode import loader
from groundstation.usercode.adapters import (
    CONTROLLER_OUTPUTS,
    UserCodeSettings,
    UserController,
    UserTrajectory,
    load_usercode_settings,
    user_planner,
)
from groundstation.usercode.guard import Guard
from groundstation.usercode.loader import UserObject, describe_error
from groundstation.usercode.quad_params import quad_params_of, select_vehicle
from model.errors import UserError
from model.vehicle import Vehicle
from model.world import World


@dataclass
class UserCode:
    settings: UserCodeSettings
    guard: Guard
    controller_output: str = "commands"
    controller: object | None = None  # the constructed SE3Control
    controller_where: str = ""
    trajectory: UserTrajectory | None = None
    planner: object | None = None  # callable for groundstation.planned
    adapters: list = field(default_factory=list)

    def controller_for(self, vehicle: Vehicle, fallback: SE3Controller, mode: str, log_dir: Path):
        """The controller the flight loop calls: the user's (adapted) or, without one, `fallback` itself."""
        if self.controller is None:
            return fallback
        adapter = UserController(self.controller, self.controller_where, vehicle, fallback, mode,
                                 self.controller_output, self.guard, self.settings, log_dir / "user_commands.csv")
        self.adapters.append(adapter)
        return adapter

    def attach(self, mission, realtime_period_s: float | None) -> None:
        """Failures of user code send the mission to its failsafe; realtime overruns are warned about."""
        self.guard.realtime_period_s = realtime_period_s
        for adapter in (*self.adapters, self.trajectory):
            if adapter is not None:
                adapter.on_fault = lambda fault: mission.user_code_failed(fault.line())

    def close(self) -> None:
        for adapter in self.adapters:
            adapter.close()

    def summary(self) -> dict:
        out: dict = {}
        for part in (*self.adapters, self.trajectory):
            if part is not None:
                out.update(part.summary())
        if self.planner is not None:
            out["planner"] = self.planner.where
        if self.guard.realtime_period_s is not None:
            out["realtime_overruns"] = self.guard.overruns
        if self.guard.fault is not None:
            out["fault"] = self.guard.fault.line()
        return out


def prepare(vehicle: Vehicle, world: World | None, controller=None, trajectory=None, planner=None,
            controller_output: str = "commands", mode: str = "moments", settings: str = "usercode") -> UserCode:
    """Load and construct what the user named (a PATH[:Name] string or the object itself)."""
    if controller_output not in CONTROLLER_OUTPUTS:
        raise UserError(f"--controller-output {controller_output}: one of {', '.join(CONTROLLER_OUTPUTS)}")
    if controller_output == "motor_speeds":
        if controller is None:
            raise UserError("--controller-output motor_speeds: only with a user controller (--controller PATH)")
        if mode != "moments":
            raise UserError("--controller-output motor_speeds: needs --mode moments (rotor speeds make a thrust "
                            "and moments, not an attitude)")
    select_vehicle(vehicle)  # flightsim.crazyflie_params describes the vehicle in use
    objects = {kind: _user_object(value, kind) for kind, value in
               (("planner", planner), ("controller", controller), ("trajectory", trajectory)) if value is not None}
    directories = [o.file.parent for o in objects.values()]
    loaded = load_usercode_settings(settings)
    code = UserCode(loaded, Guard(loaded.call_timeout_s, directories), controller_output)
    if "planner" in objects:
        p = objects["planner"]
        code.planner = user_planner(p.obj, f"{p.file.name} {p.name}", code.guard)
    if "controller" in objects:
        c = objects["controller"]
        code.controller_where = f"{c.file.name} {c.name}"
        code.controller = _construct(c, directories, f"{c.name}(quad_params)", quad_params_of(vehicle))
    if "trajectory" in objects:
        code.trajectory = _build_trajectory(objects["trajectory"], code, directories, world)
    return code


def _user_object(value, kind: str) -> UserObject:
    if isinstance(value, str | Path):
        return loader.load(str(value), kind)
    if not callable(value):
        raise UserError(f"{kind}: expected a class, a function or PATH[:Name], got {type(value).__name__}")
    module = sys.modules.get(getattr(value, "__module__", ""), None)
    file = Path(getattr(module, "__file__", None) or f"<{kind}>")
    return UserObject(value, file.resolve() if file.exists() else file, getattr(value, "__name__", kind), kind)


def _construct(user: UserObject, directories: list[Path], call: str, *args, progress: str | None = None,
               period_s: float = 0.0):
    """user.obj(*args); a failure is one UserError line. With `progress`, says every period_s that it works."""
    done = threading.Event()
    if progress:
        threading.Thread(target=_report_progress, args=(progress, period_s, done), daemon=True).start()
    try:
        return user.obj(*args)
    except Exception as err:  # noqa: BLE001 - the user's constructor failing is one line
        raise UserError(f"user code {user.file.name} {call}: raised {describe_error(err, directories)}") from None
    finally:
        done.set()


def _report_progress(what: str, period_s: float, done: threading.Event) -> None:
    start = time.monotonic()
    while not done.wait(period_s):
        print(f"cfstack: {what}: still working, {time.monotonic() - start:.0f} s (no flight clock runs yet)",
              file=sys.stderr, flush=True)


def _build_trajectory(user: UserObject, code: UserCode, directories: list[Path], world: World | None):
    from groundstation.usercode.compat.flightsim.world import World as CourseWorld

    if world is None or world.start is None or world.goal is None:
        raise UserError(f"--trajectory {user.file}: {user.name}(world, start, goal) needs a world file with a "
                        "start and a goal")
    print(f"cfstack: building {user.name} from {user.file.name} (the user's planning runs now, before the flight)",
          file=sys.stderr, flush=True)
    instance = _construct(user, directories, f"{user.name}(world, start, goal)", CourseWorld.from_model(world),
                          np.array(world.start, float), np.array(world.goal, float),
                          progress=f"building {user.name}", period_s=code.settings.build_progress_period_s)
    with code.guard:
        return UserTrajectory(instance, f"{user.file.name} {user.name}", code.settings, code.guard)
