"""The emulated vehicle's onboard sides (`--firmware`) and the vehicle file each is written for.

Takes in: a firmware name (the `--firmware` option of `cfstack fly`, `cfstack sweep` and the emulator).
Gives out: the names every command offers (FIRMWARE_VEHICLES' keys), the default one, and the vehicle
model a firmware flies when no --vehicle-model is given. No numpy here: the commands that parse
`--firmware` before loading anything heavy import this first (a mistyped option fails at once).
"""

from __future__ import annotations

# The faithful Crazyflie firmware mixes for the X-layout Crazyflie 2.1; the ideal law flies the course's
# model. A command given a firmware and no --vehicle-model flies this one; the ground station alone
# (which cannot know) flies the default's.
FIRMWARE_VEHICLES = {"ideal": "crazyflie", "crazyflie": "cf21"}
DEFAULT_FIRMWARE = "crazyflie"


def default_vehicle_model(firmware: str = DEFAULT_FIRMWARE) -> str:
    """The vehicle file (name) that `firmware` is written for."""
    return FIRMWARE_VEHICLES[firmware]
