"""Airframes: the vehicles a flight can fly, each a :class:`VehicleParams` (mass, inertia, rotors,
motors) and the :class:`ControllerParams` its PX4 airframe file sets.

Why several: a detector trained on one airframe learns that airframe's hover thrust, attitude
response and vibration; a fleet flies others. A profile's ``airframes`` mix draws one per flight
(:func:`airframe_for_seed`).

Sources, per value:

- ``iris``: the 3DR Iris of PX4's Gazebo-classic SITL (``iris.sdf``: mass 1.5 kg, inertia
  0.029125/0.029125/0.055225 kg m^2, rotors at x +-0.13 m, y +-0.22/0.20 m, motorConstant 5.84e-06,
  momentConstant 0.06, maxRotVelocity 1100 rad/s, timeConstantUp/Down 0.0125/0.025 s) flown with
  PX4's multicopter defaults (``rc.mc_defaults``; airframe 10015_gazebo-classic_iris sets no gains).
  These are :class:`VehicleParams`' and :class:`ControllerParams`' defaults, unchanged.
- ``x500``: PX4's current default SITL vehicle (Gazebo ``x500_base/model.sdf``: base_link 2.0 kg
  plus four rotor links of 0.016 kg, inertia 0.021667/0.021667/0.04 kg m^2, rotors at
  (+-0.174, +-0.174) m; ``x500/model.sdf``: motorConstant 8.54858e-06, momentConstant 0.016,
  maxRotVelocity 1000 rad/s, timeConstantUp/Down 0.0125/0.025 s, rotorDragCoefficient
  8.06428e-05). Airframe 4001_gz_x500 sets only MPC_THR_HOVER 0.60 and keeps PX4's default gains.
- ``qav250``: a 250-class racing quad, the HolyBro QAV250 of PX4's airframe 4052_holybro_qav250,
  whose gains are published there: MC_ROLL_P / MC_PITCH_P 8, MC_YAW_P 4, MC_ROLLRATE_P 0.076,
  MC_PITCHRATE_P 0.082, MC_YAWRATE_P 0.25, MC_ROLLRATE_I 0.3, MC_PITCHRATE_I 0.35, MC_YAWRATE_I 0.3,
  MC_ROLLRATE_MAX / MC_PITCHRATE_MAX 1200 deg/s, MC_YAWRATE_MAX 600 deg/s, MPC_Z_VEL_I_ACC 1.7,
  MPC_THR_HOVER 0.25 with THR_MDL_FAC 0.3. No SITL model of it is published, so its physics are
  estimated, and said so: 250 mm motor to motor (rotors at +-0.088 m), 0.75 kg with a 4S pack, inertia
  of that mass (0.0022/0.0022/0.0038 kg m^2, point masses of motors and a central body), 5-inch
  props to 2600 rad/s; the motor constant follows from MPC_THR_HOVER and THR_MDL_FAC (hover at 25 %
  throttle is 19.4 % of full thrust: 9.5 N a rotor), the moment constant is the x500's.

PX4's rate gains are normalised (a torque fraction per rad/s); this generator's are physical (rad/s^2
per rad/s). A frame's physical gain is the Iris's calibrated one (:class:`ControllerParams`) times the
ratio of the frame's PX4 gain to PX4's default times the ratio of its control authority (torque a
rotor pair can make over inertia) to the Iris's, the way PX4's allocator turns a normalised torque
into rotor thrusts; capped at what the 250 Hz rate loop with first-order motors flies stably
(:data:`RATE_P_MAX`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from scart_bench.generator.params import ControllerParams, VehicleParams

#: 1/s: the highest physical rate gain the 250 Hz rate loop (P+I, no D) flies stably with motors of
#: 12.5/25 ms time constants (tests/test_airframes.py); a frame whose PX4 gains ask for more gets this
RATE_P_MAX = 40.0

#: PX4 defaults (rc.mc_defaults, MC_*RATE_P / _I) the Iris's physical gains correspond to
_PX4_RATE_P = (0.15, 0.15, 0.2)
_PX4_RATE_I = (0.2, 0.2, 0.1)


def _authority(v: VehicleParams) -> np.ndarray:
    """Angular acceleration per unit of rotor thrust fraction (1/s^2): roll and pitch (their mean, as
    PX4's allocator normalises them together), yaw."""
    f = v.max_thrust
    x, y = np.abs(v.rotor_x), np.abs(v.rotor_y)
    rp = (y.sum() * f / v.inertia[0] + x.sum() * f / v.inertia[1]) / 2
    return np.array([rp, rp, len(v.rotor_x) * v.moment_constant * f / v.inertia[2]])


def _physical_gains(v: VehicleParams, rate_p: tuple, rate_i: tuple) -> tuple[tuple, tuple]:
    """Physical rate P and I gains for PX4's normalised ``rate_p`` / ``rate_i`` on vehicle ``v``."""
    base = ControllerParams()
    scale = _authority(v) / _authority(VehicleParams())
    p = np.minimum(np.array(base.rate_p) * np.array(rate_p) / _PX4_RATE_P * scale, RATE_P_MAX)
    i = np.array(base.rate_i) * np.array(rate_i) / _PX4_RATE_I * (p / np.array(base.rate_p))
    return tuple(float(a) for a in p), tuple(float(a) for a in i)


def _x500() -> tuple[VehicleParams, ControllerParams]:
    v = VehicleParams(
        mass=2.0 + 4 * 0.016076923, inertia=(0.02166666666666667, 0.02166666666666667, 0.04000000000000001),
        # Gazebo (FLU) rotor_0 (0.174, -0.174) ccw, rotor_1 (-0.174, 0.174) ccw, rotor_2 (0.174, 0.174) cw,
        # rotor_3 (-0.174, -0.174) cw; in FRD y flips, and a ccw rotor yaws the body +z (as the Iris's)
        rotor_x=(0.174, -0.174, 0.174, -0.174), rotor_y=(0.174, -0.174, -0.174, 0.174),
        rotor_spin=(1.0, 1.0, -1.0, -1.0), motor_constant=8.54858e-06, moment_constant=0.016,
        max_rot_velocity=1000.0, time_constant_up=0.0125, time_constant_down=0.025,
        rotor_drag_coefficient=8.06428e-05, body_drag=0.06)
    rate_p, rate_i = _physical_gains(v, _PX4_RATE_P, _PX4_RATE_I)
    return v, dataclasses.replace(ControllerParams(), rate_p=rate_p, rate_i=rate_i)


def _qav250() -> tuple[VehicleParams, ControllerParams]:
    mass = 0.75
    hover_fraction = 0.3 * 0.25**2 + 0.7 * 0.25  # THR_MDL_FAC 0.3 at MPC_THR_HOVER 0.25
    per_rotor = mass * 9.80665 / (4 * hover_fraction)
    arm = 0.125 / np.sqrt(2.0)
    v = VehicleParams(
        mass=mass, inertia=(0.0022, 0.0022, 0.0038),
        rotor_x=(arm, -arm, arm, -arm), rotor_y=(arm, -arm, -arm, arm), rotor_spin=(1.0, 1.0, -1.0, -1.0),
        motor_constant=float(per_rotor / 2600.0**2), moment_constant=0.016, max_rot_velocity=2600.0,
        time_constant_up=0.0125, time_constant_down=0.025, rotor_drag_coefficient=2.0e-05, body_drag=0.02)
    rate_p, rate_i = _physical_gains(v, (0.076, 0.082, 0.25), (0.3, 0.35, 0.3))
    c = dataclasses.replace(
        ControllerParams(), att_p=(8.0, 8.0, 4.0), rate_p=rate_p, rate_i=rate_i, vel_z_i=1.7,
        rate_max=(float(np.deg2rad(1200)), float(np.deg2rad(1200)), float(np.deg2rad(600))))
    return v, c


#: name -> (vehicle, controller)
AIRFRAMES: dict[str, tuple[VehicleParams, ControllerParams]] = {
    "iris": (VehicleParams(), ControllerParams()),
    "x500": _x500(),
    "qav250": _qav250(),
}


def airframe(name: str) -> tuple[VehicleParams, ControllerParams]:
    """The vehicle and controller of airframe ``name`` (ValueError naming the known ones otherwise)."""
    if name not in AIRFRAMES:
        raise ValueError(f"airframe {name!r}: expected one of {', '.join(AIRFRAMES)}")
    return AIRFRAMES[name]


def check_mix(mix, what: str, known) -> tuple[tuple[str, float], ...]:
    """``mix`` (name -> weight, or pairs) as sorted (name, weight) pairs with weights summing to 1;
    ValueError naming ``what``, the entry and what was expected otherwise."""
    pairs = sorted(dict(mix).items())
    for name, w in pairs:
        if name not in known:
            raise ValueError(f"{what} {name!r}: expected one of {', '.join(known)}")
        if not isinstance(w, (int, float)) or isinstance(w, bool) or not np.isfinite(w) or w < 0:
            raise ValueError(f"{what} {name!r}: weight {w!r}, expected a number >= 0")
    total = sum(w for _, w in pairs)
    if not pairs or total <= 0:
        raise ValueError(f"{what} mix: expected at least one positive weight, got {dict(mix)!r}")
    return tuple((name, float(w) / total) for name, w in pairs)


def pick(mix: tuple[tuple[str, float], ...], u: float) -> str:
    """The entry of ``mix`` (sorted pairs summing to 1) that the uniform draw ``u`` in [0, 1) falls in."""
    edges = np.cumsum([w for _, w in mix])
    return mix[min(int(np.searchsorted(edges, u, side="right")), len(mix) - 1)][0]


def airframe_for_seed(mix: tuple[tuple[str, float], ...], seed: int) -> str:
    """The airframe the flight with ``seed`` flies (its own stream: the same in any batch, and for
    the attacked flights flown from that seed)."""
    g = np.random.default_rng(np.random.SeedSequence([int(seed), 0xA12F]))
    return pick(mix, float(g.random()))
