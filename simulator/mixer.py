"""Mixer: collective thrust and body moments -> rotor speeds, with attitude-first saturation.

Takes in: a Vehicle (its allocation A: [T, Mx, My, Mz]^T = A [w_1^2 .. w_4^2]^T, rotor speed limits),
then thrust T (N) and body moments M (FLU, N m) per call.
Gives out: four rotor speeds (rad/s) within [w_min, w_max].

Saturation (the PX4 / Crazyflie "attitude first" idea, solved exactly rather than iteratively):
w^2 = A^-1 [T, M] = T c + u_rp + u_yaw, where c = A^-1 e1 is the collective direction (changes thrust
only) and u_rp, u_yaw are the roll/pitch and yaw parts (they change no thrust). Every rotor must satisfy
w_min^2 <= w_i^2 <= w_max^2.
  1. If the roll/pitch part alone cannot fit for any collective, it is scaled down (direction kept) to
     the largest fraction that fits, and yaw is dropped.
  2. Otherwise yaw is scaled by the largest fraction in [0, 1] that still fits beside roll/pitch.
  3. The collective is then the feasible one nearest to the commanded thrust.
So under saturation roll and pitch moments are met exactly while thrust gives way, then yaw; the
request is met exactly whenever it is feasible. The fast path (no saturation) is plain Python floats.
"""

from __future__ import annotations

import math

import numpy as np

from model.vehicle import Vehicle


class Mixer:
    def __init__(self, vehicle: Vehicle):
        self.allocation = np.asarray(vehicle.allocation, float)
        inverse = np.linalg.inv(self.allocation)
        self._inverse = inverse
        self._inv_rows = tuple(tuple(float(v) for v in row) for row in inverse)
        self.collective = inverse[:, 0].copy()  # w^2 per newton of thrust
        if np.any(self.collective <= 0.0):
            raise ValueError(f"{vehicle.source}: rotor layout where thrust does not raise every rotor")
        self.w2_min = vehicle.rotor_speed_min_radps ** 2
        self.w2_max = vehicle.rotor_speed_max_radps ** 2

    def mix(self, thrust_n: float, moment_flu_nm) -> tuple[float, float, float, float]:
        """Rotor speeds (rad/s) giving thrust_n and moment_flu_nm, saturated attitude first."""
        mx, my, mz = moment_flu_nm
        lo, hi = self.w2_min, self.w2_max
        r0, r1, r2, r3 = self._inv_rows
        w0 = r0[0] * thrust_n + r0[1] * mx + r0[2] * my + r0[3] * mz
        w1 = r1[0] * thrust_n + r1[1] * mx + r1[2] * my + r1[3] * mz
        w2 = r2[0] * thrust_n + r2[1] * mx + r2[2] * my + r2[3] * mz
        w3 = r3[0] * thrust_n + r3[1] * mx + r3[2] * my + r3[3] * mz
        if lo <= w0 <= hi and lo <= w1 <= hi and lo <= w2 <= hi and lo <= w3 <= hi:
            sqrt = math.sqrt
            return (sqrt(w0), sqrt(w1), sqrt(w2), sqrt(w3))
        return tuple(math.sqrt(v) for v in self.saturated_w2(thrust_n, mx, my, mz).tolist())

    def saturated_w2(self, thrust_n: float, mx: float, my: float, mz: float) -> np.ndarray:
        """Squared rotor speeds by the attitude-first rule of the module docstring."""
        inv = self._inverse
        roll_pitch = inv[:, 1] * mx + inv[:, 2] * my
        yaw = inv[:, 3] * mz
        zero = np.zeros(4)
        keep_rp = self._largest_fitting_scale(zero, roll_pitch)
        if keep_rp < 1.0:
            base = keep_rp * roll_pitch
        else:
            base = roll_pitch + self._largest_fitting_scale(roll_pitch, yaw) * yaw
        low, high = self._collective_range(base)
        collective = min(max(thrust_n, low), high)
        return np.clip(base + collective * self.collective, self.w2_min, self.w2_max)  # clip: rounding only

    def wrench(self, rotor_speeds_radps) -> np.ndarray:
        """[T (N), Mx, My, Mz (N m)] produced by the given rotor speeds."""
        return self.allocation @ (np.asarray(rotor_speeds_radps, float) ** 2)

    def _collective_range(self, base: np.ndarray) -> tuple[float, float]:
        """Thrust interval [low, high] (N) keeping base + thrust * c inside the rotor limits."""
        c = self.collective
        return float(np.max((self.w2_min - base) / c)), float(np.min((self.w2_max - base) / c))

    def _largest_fitting_scale(self, fixed: np.ndarray, part: np.ndarray) -> float:
        """Largest s in [0, 1] such that some collective fits fixed + s * part within the limits.

        A collective fits iff for all rotors i, j: (lo - b_i)/c_i <= (hi - b_j)/c_j, i.e.
        b_j/c_j - b_i/c_i <= hi/c_j - lo/c_i, each linear in s: solve every pair, keep the tightest.
        """
        c = self.collective
        f, p = fixed / c, part / c
        slack = (self.w2_max / c)[None, :] - (self.w2_min / c)[:, None] - (f[None, :] - f[:, None])
        growth = p[None, :] - p[:, None]
        growing = growth > 0.0
        if not np.any(growing):
            return 1.0
        with np.errstate(over="ignore"):  # a vanishing growth means no limit (inf)
            limits = slack[growing] / growth[growing]
        return float(min(1.0, max(0.0, limits.min())))
