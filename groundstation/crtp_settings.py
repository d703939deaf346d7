"""The ground station's Crazyflie link settings, from groundstation/params/crtp_link.toml.

Takes in: a settings name or TOML path (default "crtp_link").
Gives out: link.crtp.cflib_link.CrtpLinkSettings (a one-line UserError for a bad file).
"""

from __future__ import annotations

from pathlib import Path

from link.crtp.cflib_link import CrtpLinkSettings
from model.config import Params, resolve


def load_crtp_link_settings(name_or_path: str | Path = "crtp_link") -> CrtpLinkSettings:
    p = Params.load(resolve(name_or_path, "groundstation", "params", "Crazyflie link settings"))
    log, thrust, commander = p.table("log"), p.table("thrust"), p.table("commander")
    return CrtpLinkSettings(
        imu_period_ms=int(log.number("imu_period_ms", minimum=10, maximum=2550)),
        status_period_ms=int(log.number("status_period_ms", minimum=10, maximum=2550)),
        per_motor_max_n=thrust.number("per_motor_max_n", minimum=1e-6),
        pwm_full=int(thrust.number("pwm_full", minimum=1)),
        rpyt_max_pwm=int(thrust.number("rpyt_max_pwm", minimum=0, maximum=65535)),
        unlock_after_silence_s=commander.number("unlock_after_silence_s", minimum=0.0),
        land_duration_per_m_s=commander.number("land_duration_per_m_s", minimum=0.0),
        connect_timeout_s=p.table("connect").number("timeout_s", minimum=0.1),
    )
