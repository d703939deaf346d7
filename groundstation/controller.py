"""Geometric SE(3) tracking controller: the lab report's law, optionally with Lee et al.'s feed-forward.

Takes in: the vehicle's state (position/velocity world ENU, attitude quaternion (w, x, y, z) body FLU ->
world ENU, body rates FLU) and a reference FlatOutput (position, velocity, acceleration, jerk, snap,
yaw, yaw rate); gains from a gains TOML (groundstation/params/gains.toml) and the vehicle model
(mass, inertia, thrust and moment limits) from model.vehicle.
Gives out: a ControlOutput: collective thrust u1 (N) clipped to [0, max thrust], body moment u2 (N m, FLU)
clipped per axis to +-max moment (with saturation flags), the desired attitude R_des as a quaternion, the
desired body rate, and the errors for logging.

Equations (lab report section II, paper notation, SI):
    r_des'' = r_T'' - K_d (r' - r_T') - K_p (r - r_T)                       [m/s^2]
    F_des   = m r_des'' + [0, 0, m g]                                       [N]
    u1      = b3 . F_des,  b3 = R e3                                        [N]
    b3_des  = F_des / |F_des|,  a_psi = [cos psi_T, sin psi_T, 0]
    b2_des  = (b3_des x a_psi) / |b3_des x a_psi|,  R_des = [b2_des x b3_des, b2_des, b3_des]
    e_R     = 1/2 vee(R_des^T R - R^T R_des),  e_w = w - w_des
    u2      = I (-K_R e_R - K_w e_w)                                        [N m]  (model.attitude_law)
variant "report": w_des = 0 (as flown in the report).
variant "full" (Lee, Leok, McClamroch 2010, with Mellinger & Kumar 2011's flat-output rates):
    h_w     = m/|F_des| (j_T - (b3_des . j_T) b3_des)
    w_des   = [-h_w . b2_des, h_w . b1_des, w_z]                            (in the R_des frame)
    w_z     = (psi_T' (e3 x a_psi) . b2_des + (a_psi . b3_des) w_x) / |b3_des x a_psi|
    h_a     = m/|F_des| s_T - 2 (m b3_des . j_T / |F_des|) h_w - w_des_world x h_w
    w'_des  = [-h_a . b2_des, h_a . b1_des, d/dt w_z]                       (psi_T'' taken as 0)
    e_w     = w - R^T R_des w_des
    u2      = I (-K_R e_R - K_w e_w) + w x I w - I (w^ R^T R_des w_des - R^T R_des w'_des)
w_z is exact for this R_des construction (w_z = b2_des . d/dt b1_des). Mellinger & Kumar's
w_z = psi_T' e3 . b3_des is its special case a_psi . b3_des = 0 (tilt only across the heading); it misses
the twist about b3_des when tilting along the heading, which is large on a fast circle.

The update runs at 500 Hz, so it is written on plain floats: a dozen small numpy operations would cost
more than the whole computation (see benchmarks/controller_bench.py). For the same reason the gains and
limits are unpacked into float attributes once, at construction.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from groundstation.controller_kernel import report_constants, se3_update
from groundstation.trajectory import FlatOutput
from model.attitude_law import attitude_moment
from model.config import Params, resolve
from model.errors import ConfigError
from model.frames import quat_normalize, quat_to_rows, rows_to_quat
from model.vehicle import GRAVITY_MPS2, Vehicle

VARIANTS = ("report", "full")

# Numerical guard, not a tuning parameter: below this |F_des| (N) or |b3_des x a_psi| the direction is
# undefined (commanded free fall, or b3_des along the heading), and a fallback direction is used.
_DEGENERATE_NORM = 1e-9

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]


@dataclass(frozen=True)
class Gains:
    """Diagonal gains of the controller and the model corrections it applies."""

    kp: Vec3  # 1/s^2, diag K_p
    kd: Vec3  # 1/s, diag K_d
    k_r: Vec3  # 1/s^2, diag K_R (inertia-normalised)
    k_w: Vec3  # 1/s, diag K_w (inertia-normalised)
    mass_offset_kg: float = 0.0  # added to the vehicle's mass in the model
    variant: str = "report"  # "report" | "full"
    name: str = ""
    source: str = ""


def load_gains(name_or_path: str | Path = "gains") -> Gains:
    """Gains from a TOML file, or the built-in file of that name ("gains"; "default" is the same file)."""
    if str(name_or_path) == "default":
        name_or_path = "gains"
    params = Params.load(resolve(name_or_path, "groundstation", "params", "gains"))
    position = params.table("position")
    attitude = params.table("attitude")
    return Gains(
        kp=_positive_diagonal(position, "kp"),
        kd=_positive_diagonal(position, "kd"),
        k_r=_positive_diagonal(attitude, "k_r"),
        k_w=_positive_diagonal(attitude, "k_w"),
        mass_offset_kg=params.number("mass_offset_kg", default=0.0),
        variant=params.string("variant", choices=VARIANTS, default="report"),
        name=params.string("name"),
        source=params.string("source"),
    )


def _positive_diagonal(params: Params, key: str) -> Vec3:
    values = params.vector(key, 3)
    if min(values) <= 0.0:
        raise params.error(key, f"gains must be positive, got {values}")
    return (values[0], values[1], values[2])


@dataclass(frozen=True)
class ControllerState:
    """What the controller needs to know of the vehicle (plain tuples or numpy arrays)."""

    position_enu_m: Sequence[float]
    velocity_enu_mps: Sequence[float]
    attitude_wxyz: Sequence[float]
    rate_flu_radps: Sequence[float]


@dataclass(frozen=True, slots=True)
class ControlOutput:
    thrust_n: float  # u1, clipped to [0, max thrust]
    moment_flu_nm: Vec3  # u2, clipped per axis to +-max moment
    attitude_des_wxyz: Quat  # R_des
    rate_des_flu_radps: Vec3  # w_des in the R_des frame (zero in the "report" variant)
    thrust_saturated: bool
    moment_saturated: tuple[bool, bool, bool]
    force_des_enu_n: Vec3  # F_des before projection onto b3
    position_error_m: Vec3  # r - r_T, world ENU
    velocity_error_mps: Vec3  # r' - r_T', world ENU
    e_R: Vec3  # attitude error, dimensionless (sin of the angle for a single-axis error)
    e_w: Vec3  # rate error w - R^T R_des w_des, rad/s body FLU

    @property
    def saturated(self) -> bool:
        return self.thrust_saturated or any(self.moment_saturated)


def as_floats(v):
    """A 3- or 4-vector as Python floats (numpy scalars make float arithmetic several times slower)."""
    return v.tolist() if type(v) is np.ndarray else v


def _clip(value: float, low: float, high: float) -> float:
    """value limited to [low, high]; NaN passes through (and is then flagged as saturated: NaN != NaN)."""
    return high if value > high else low if value < low else value


class SE3Controller:
    """The geometric controller of the lab report; `variant="full"` adds Lee et al.'s feed-forward."""

    def __init__(self, vehicle: Vehicle, gains: Gains, variant: str | None = None):
        self.variant = gains.variant if variant is None else variant
        if self.variant not in VARIANTS:
            raise ConfigError(f"controller variant '{self.variant}' is not one of {', '.join(VARIANTS)}")
        self.mass_kg = vehicle.mass_kg + gains.mass_offset_kg
        if self.mass_kg <= 0.0:
            raise ConfigError(f"{gains.source or gains.name}: mass_offset_kg: {gains.mass_offset_kg} leaves "
                              f"the model mass {self.mass_kg:.4g} kg non-positive")
        self.gains = gains
        self.vehicle = vehicle
        self._inertia_diag = tuple(np.diag(vehicle.inertia_kgm2).tolist())  # model.vehicle: diagonal, body FLU
        self._max_thrust_n = float(vehicle.max_thrust_n)
        self._max_moment_nm = tuple(np.asarray(vehicle.max_moment_nm, dtype=float).tolist())
        self._full = self.variant == "full"
        self._position_gains = (*gains.kp, *gains.kd)
        self._report_constants = None  # the compiled report law's constants (None: the Python runs)
        if se3_update is not None and not self._full:
            self._report_constants = report_constants(self.mass_kg, self._position_gains, gains.k_r, gains.k_w,
                                                      self._inertia_diag, self._max_thrust_n, self._max_moment_nm,
                                                      _DEGENERATE_NORM)

    def update(self, state: ControllerState, ref: FlatOutput, t_s: float = 0.0) -> ControlOutput:  # noqa: ARG002
        # t_s is unused (the law is time-invariant); it is the course's update(t, ...) argument, which the
        # user-code adapter (groundstation.usercode) takes through this same call
        """One control step: thrust, moment and desired attitude for the current state and reference.
        The "report" law is compiled (controller_kernel), with _update_python as its twin."""
        if self._report_constants is not None:
            out = se3_update(state.position_enu_m, state.velocity_enu_mps, state.attitude_wxyz, state.rate_flu_radps,
                             ref.position_m, ref.velocity_mps, ref.acceleration_mps2, ref.yaw_rad,
                             self._report_constants, ControlOutput)
            if out is not None:
                return out
        return self._update_python(state, ref)  # not built, the "full" variant, or a step the kernel leaves

    def _update_python(self, state: ControllerState, ref: FlatOutput) -> ControlOutput:
        """The law in Python: the compiled report law's twin, and the "full" variant."""
        m = self.mass_kg
        kpx, kpy, kpz, kdx, kdy, kdz = self._position_gains
        px, py, pz = as_floats(state.position_enu_m)
        vx, vy, vz = as_floats(state.velocity_enu_mps)
        tx, ty, tz = as_floats(ref.position_m)
        tvx, tvy, tvz = as_floats(ref.velocity_mps)
        tax, tay, taz = as_floats(ref.acceleration_mps2)

        # Position loop: F_des = m (r_T'' - K_d e_v - K_p e_p) + m g e3.
        epx, epy, epz = px - tx, py - ty, pz - tz
        evx, evy, evz = vx - tvx, vy - tvy, vz - tvz
        fx = m * (tax - kdx * evx - kpx * epx)
        fy = m * (tay - kdy * evy - kpy * epy)
        fz = m * (taz - kdz * evz - kpz * epz + GRAVITY_MPS2)

        r00, r01, r02, r10, r11, r12, r20, r21, r22 = quat_to_rows(quat_normalize(as_floats(state.attitude_wxyz)))
        thrust = r02 * fx + r12 * fy + r22 * fz  # u1 = (R e3) . F_des

        # Desired body axes.
        f_norm = math.sqrt(fx * fx + fy * fy + fz * fz)
        if f_norm > _DEGENERATE_NORM:
            b3x, b3y, b3z = fx / f_norm, fy / f_norm, fz / f_norm
        else:  # free fall commanded: keep the current thrust axis
            b3x, b3y, b3z = r02, r12, r22
        psi = ref.yaw_rad
        ax, ay = math.cos(psi), math.sin(psi)
        cx, cy, cz = -b3z * ay, b3z * ax, b3x * ay - b3y * ax  # b3_des x a_psi, a_psi = (ax, ay, 0)
        c_norm = math.sqrt(cx * cx + cy * cy + cz * cz)
        heading_norm = c_norm  # |b3_des x a_psi|, needed by the yaw feed-forward
        if c_norm <= _DEGENERATE_NORM:  # b3_des along the heading: use the current b1 as heading instead
            cx, cy, cz = b3y * r20 - b3z * r10, b3z * r00 - b3x * r20, b3x * r10 - b3y * r00
            c_norm = math.sqrt(cx * cx + cy * cy + cz * cz)
            if c_norm <= _DEGENERATE_NORM:  # and along the current b1: so the current b2 is normal to it
                cx, cy, cz, c_norm = r01, r11, r21, 1.0
        b2x, b2y, b2z = cx / c_norm, cy / c_norm, cz / c_norm
        b1x, b1y, b1z = b2y * b3z - b2z * b3y, b2z * b3x - b2x * b3z, b2x * b3y - b2y * b3x

        # M = R_des^T R, M[i][j] = b_i_des . (column j of R); e_R = 1/2 vee(M - M^T).
        m01 = b1x * r01 + b1y * r11 + b1z * r21
        m02 = b1x * r02 + b1y * r12 + b1z * r22
        m10 = b2x * r00 + b2y * r10 + b2z * r20
        m12 = b2x * r02 + b2y * r12 + b2z * r22
        m20 = b3x * r00 + b3y * r10 + b3z * r20
        m21 = b3x * r01 + b3y * r11 + b3z * r21
        erx, ery, erz = 0.5 * (m21 - m12), 0.5 * (m02 - m20), 0.5 * (m10 - m01)

        wx, wy, wz = as_floats(state.rate_flu_radps)
        e_r = (erx, ery, erz)
        gains = self.gains
        if self._full and f_norm > _DEGENERATE_NORM and heading_norm > _DEGENERATE_NORM:
            wd, wdb, adb = self._feed_forward(
                ref, m / f_norm, (ax, ay, heading_norm), (b1x, b1y, b1z), (b2x, b2y, b2z), (b3x, b3y, b3z),
                (m01, m02, m10, m12, m20, m21,
                 b1x * r00 + b1y * r10 + b1z * r20, b2x * r01 + b2y * r11 + b2z * r21,
                 b3x * r02 + b3y * r12 + b3z * r22))
            ewx, ewy, ewz = wx - wdb[0], wy - wdb[1], wz - wdb[2]
            # Feed-forward angular acceleration: R^T R_des w'_des - w x (R^T R_des w_des).
            alpha_ff = (adb[0] - (wy * wdb[2] - wz * wdb[1]), adb[1] - (wz * wdb[0] - wx * wdb[2]),
                        adb[2] - (wx * wdb[1] - wy * wdb[0]))
            mx, my, mz = attitude_moment(e_r, (ewx, ewy, ewz), gains.k_r, gains.k_w, self._inertia_diag,
                                         (wx, wy, wz), alpha_ff)
        else:  # the lab report's law: w_des = 0, no gyroscopic term
            wd = (0.0, 0.0, 0.0)
            ewx, ewy, ewz = wx, wy, wz
            mx, my, mz = attitude_moment(e_r, (ewx, ewy, ewz), gains.k_r, gains.k_w, self._inertia_diag)

        thrust_clipped = _clip(thrust, 0.0, self._max_thrust_n)
        lx, ly, lz = self._max_moment_nm
        moment = (_clip(mx, -lx, lx), _clip(my, -ly, ly), _clip(mz, -lz, lz))
        # Positional: keyword arguments make building this frozen dataclass a third slower.
        return ControlOutput(thrust_clipped, moment, rows_to_quat(b1x, b2x, b3x, b1y, b2y, b3y, b1z, b2z, b3z),
                             wd, thrust_clipped != thrust, (moment[0] != mx, moment[1] != my, moment[2] != mz),
                             (fx, fy, fz), (epx, epy, epz), (evx, evy, evz), e_r, (ewx, ewy, ewz))

    @staticmethod
    def _feed_forward(ref: FlatOutput, m_over_f: float, heading: Vec3, b1: Vec3, b2: Vec3, b3: Vec3,
                      m_entries: tuple[float, ...]) -> tuple[Vec3, Vec3, Vec3]:
        """w_des, and R^T R_des w_des, R^T R_des w'_des in the body frame, from the reference jerk and snap.

        Differentiating m r'' = u1 b3 - m g e3 gives m j = u1' b3 + u1 (w x b3), and w x b3 = w_y b1 - w_x b2
        (w in the R_des frame); once more, m s = u1'' b3 + 2 u1' (w x b3) + u1 (w' x b3 + w x (w x b3)).
        Yaw: b1 = (a - (a.b3) b3)/n with n = |b3 x a| gives w_z = b2 . b1' = (a' . b2 - (a.b3) b3' . b2)/n,
        a' = psi' e3 x a and b3' . b2 = -w_x; w_z' follows by the quotient rule (psi'' = 0).
        `heading` is (cos psi, sin psi, n).
        """
        jx, jy, jz = as_floats(ref.jerk_mps3)
        sx, sy, sz = as_floats(ref.snap_mps4)
        psi_rate = ref.yaw_rate_radps
        b1x, b1y, b1z = b1
        b2x, b2y, b2z = b2
        b3x, b3y, b3z = b3
        b3j = b3x * jx + b3y * jy + b3z * jz
        hx, hy, hz = m_over_f * (jx - b3j * b3x), m_over_f * (jy - b3j * b3y), m_over_f * (jz - b3j * b3z)
        wd0 = -(hx * b2x + hy * b2y + hz * b2z)
        wd1 = hx * b1x + hy * b1y + hz * b1z
        ax, ay, n = heading
        a_b3 = ax * b3x + ay * b3y  # a_psi . b3_des
        apx, apy = -ay, ax  # e3 x a_psi, the heading's rate direction
        wd2 = (psi_rate * (apx * b2x + apy * b2y) + a_b3 * wd0) / n
        # w_des in world coordinates, crossed with h_w (= w x b3): the w x (w x b3) term.
        ox = wd0 * b1x + wd1 * b2x + wd2 * b3x
        oy = wd0 * b1y + wd1 * b2y + wd2 * b3y
        oz = wd0 * b1z + wd1 * b2z + wd2 * b3z
        u1_rate_ratio = 2.0 * m_over_f * b3j  # 2 u1' / u1
        hax = m_over_f * sx - u1_rate_ratio * hx - (oy * hz - oz * hy)
        hay = m_over_f * sy - u1_rate_ratio * hy - (oz * hx - ox * hz)
        haz = m_over_f * sz - u1_rate_ratio * hz - (ox * hy - oy * hx)
        ad0 = -(hax * b2x + hay * b2y + haz * b2z)
        ad1 = hax * b1x + hay * b1y + haz * b1z
        # w_z = A / n: A' = psi' (a'' . b2 + a' . b2') + (a.b3)' w_x + (a.b3) w_x', n' = -(a.b3)(a.b3)'/n,
        # with a'' = -psi'^2 a, (a.b3)' = a' . b3 + a . h_w, b2' = w x b2.
        a_b3_rate = psi_rate * (apx * b3x + apy * b3y) + ax * hx + ay * hy
        b2dx, b2dy = oy * b2z - oz * b2y, oz * b2x - ox * b2z
        a_rate = (psi_rate * (-psi_rate * (ax * b2x + ay * b2y) + apx * b2dx + apy * b2dy)
                  + a_b3_rate * wd0 + a_b3 * ad0)
        ad2 = (a_rate + wd2 * a_b3 * a_b3_rate / n) / n
        # R^T R_des = M^T: (M^T v)_i = sum_j M[j][i] v_j.
        m01, m02, m10, m12, m20, m21, m00, m11, m22 = m_entries
        wdb = (m00 * wd0 + m10 * wd1 + m20 * wd2, m01 * wd0 + m11 * wd1 + m21 * wd2,
               m02 * wd0 + m12 * wd1 + m22 * wd2)
        adb = (m00 * ad0 + m10 * ad1 + m20 * ad2, m01 * ad0 + m11 * ad1 + m21 * ad2,
               m02 * ad0 + m12 * ad1 + m22 * ad2)
        return (wd0, wd1, wd2), wdb, adb
