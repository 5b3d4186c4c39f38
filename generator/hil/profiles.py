"""What the flight software must know of an external simulator's vehicle and sensors.

The controller's gains are in physical units (torque = inertia x gain x rate error), so the same
cascade flies another airframe once it knows that airframe's mass, inertia, rotor layout and
rotor thrust. The values of :data:`JMAVSIM` are jMAVSim's default quadrotor
(``Simulator.buildMulticopter``): 0.8 kg, arms of 0.165 m in PX4's quad-x order, rotors of 4 N
full thrust and 0.05 N m full torque, thrust linear in the command (``Rotor.getThrust``), GPS
delayed 200 ms, the magnetic field ``DEFAULT_MAG_FIELD``.

jMAVSim's airframe has little drag (0.01 N s^2/m^2, no rotor drag; the Iris of the built-in engine
loses about 1.7 m/s^2 to drag at 5 m/s), and the velocity loop, tuned with that damping, overshot
every corner of the mission by up to 3.2 m. Its velocity P gain (MPC_XY_VEL_P_ACC, PX4's range
1.2-5) is raised from 1.8 to 2.5 for jMAVSim: the corners then stay within about 2.1 m (measured).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from scart_bench.generator.params import ControllerParams, VehicleParams


@dataclass(frozen=True)
class SimProfile:
    """An external simulator's airframe and sensors as the bridge's flight software sees them."""

    name: str
    vehicle: VehicleParams
    #: the simulator's magnetic field (NED, gauss): the estimator's declination comes from it
    mag_field_ned: tuple[float, float, float]
    #: how old a HIL_GPS fix is when it arrives (s): the estimator fuses it against its past state
    gps_delay_s: float
    #: True when a rotor's thrust is linear in its command (jMAVSim); False: quadratic (rotor speed
    #: linear in the command, as PX4's Gazebo-classic motor model)
    thrust_linear: bool = True
    #: HIL_STATE_QUATERNION.alt: "ned_z" (jMAVSim sends its local z in mm) or "amsl" (the MAVLink
    #: definition, mm above mean sea level)
    truth_alt: str = "amsl"
    #: the cascade's tuning for this airframe (PX4 tunes MPC_* / MC_* per airframe too)
    controller: ControllerParams = field(default_factory=ControllerParams)

    def controls(self, rotor_speed: np.ndarray) -> np.ndarray:
        """Motor commands 0..1 for the rotor speeds (rad/s) the controller's mixer asks for."""
        frac = np.clip(np.asarray(rotor_speed, dtype=float) / self.vehicle.max_rot_velocity, 0.0, 1.0)
        return frac**2 if self.thrust_linear else frac


def _jmavsim_vehicle() -> VehicleParams:
    arm = 0.33 / 2
    d = arm / np.sqrt(2.0)
    full_thrust, full_torque, max_rot = 4.0, 0.05, 1000.0
    return VehicleParams(
        mass=0.8, inertia=(0.005, 0.005, 0.009),
        rotor_x=(d, -d, d, -d), rotor_y=(d, -d, -d, d), rotor_spin=(1.0, 1.0, -1.0, -1.0),
        motor_constant=full_thrust / max_rot**2, moment_constant=full_torque / full_thrust,
        max_rot_velocity=max_rot, time_constant_up=0.005, time_constant_down=0.005,
        rotor_drag_coefficient=0.0, body_drag=0.01,
    )


JMAVSIM = SimProfile(name="jmavsim", vehicle=_jmavsim_vehicle(), mag_field_ned=(0.21506, 0.01021, 0.42974),
                     gps_delay_s=0.2, thrust_linear=True, truth_alt="ned_z",
                     controller=ControllerParams(vel_xy_p=2.5))

PROFILES = {"jmavsim": JMAVSIM}
