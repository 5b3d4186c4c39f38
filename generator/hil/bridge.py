"""The bridge: the project's flight software as the autopilot side of PX4's simulator MAVLink API.

::

    simulator --HIL_SENSOR, HIL_GPS--> [SCART layer, point sensor] --> estimator --telemetry-->
        [SCART layer, point link] --> navigator --setpoint--> cascade --HIL_ACTUATOR_CONTROLS--> simulator
    simulator --HIL_STATE_QUATERNION (ground truth)--> the flight's simulator view

In lockstep every HIL_SENSOR is answered by one HIL_ACTUATOR_CONTROLS, which is what advances the
simulator's clock, so the flight runs as fast as both sides compute (faster than real time).
Without lockstep the same loop follows the simulator's own clock. :func:`fly` flies one mission;
:func:`replay` feeds a flown flight's sensor samples to a fresh flight software (no simulator).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from scart_bench.dataset.schema import HOME_ALT
from scart_bench.generator.geo import latlon_to_ned
from scart_bench.generator.hil.autopilot import GpsSample, HilAutopilot, SensorSample
from scart_bench.generator.hil.errors import HilError
from scart_bench.generator.hil.link import SimLink
from scart_bench.generator.params import CRASH_TILT_RAD
from scart_bench.generator.physics.rotation import euler_from_quat

#: seconds after the land detector disarms that the flight is still recorded (as the built-in engine)
TAIL_S = 0.5


@dataclass
class HilFlight:
    """One flight through the bridge.

    ``truth``: (n, 12) ground truth from HIL_STATE_QUATERNION rows ``t_us, x, y, z, vx, vy, vz,
    roll, pitch, yaw``, the step it arrived before and whether the motors were armed; ``estimate``: (n, 6) step, x, y, z of the
    estimator's output, the navigator's phase and item; ``inputs``: every sensor sample with the fix that came with it (for
    :func:`replay`); ``outputs``: (steps, 4) motor commands sent.
    """

    autopilot: HilAutopilot
    status: str
    steps: int
    wall_s: float
    truth: np.ndarray
    estimate: np.ndarray
    inputs: list[tuple[SensorSample, GpsSample | None]] = field(default_factory=list)
    outputs: np.ndarray | None = None

    @property
    def sim_s(self) -> float:
        return self.steps * 0.004

    @property
    def speed(self) -> float:
        """Simulated seconds per wall second."""
        return self.sim_s / max(self.wall_s, 1e-9)


def sensor_sample(m) -> SensorSample:
    """A HIL_SENSOR message as the flight software's sample (pressure hPa -> Pa)."""
    return SensorSample(t_us=int(m.time_usec), accel=np.array([m.xacc, m.yacc, m.zacc], dtype=float),
                        gyro=np.array([m.xgyro, m.ygyro, m.zgyro], dtype=float),
                        mag=np.array([m.xmag, m.ymag, m.zmag], dtype=float), pressure=float(m.abs_pressure) * 100.0,
                        temperature=float(m.temperature) if m.temperature else 15.0)


def gps_sample(m) -> GpsSample:
    """A HIL_GPS message as the flight software's fix (1e7 deg, mm, cm, cm/s -> deg, m, m, m/s)."""
    return GpsSample(lat=m.lat * 1e-7, lon=m.lon * 1e-7, alt=m.alt * 1e-3,
                     vel=np.array([m.vn, m.ve, m.vd], dtype=float) * 0.01, eph=m.eph * 0.01, epv=m.epv * 0.01,
                     satellites=float(m.satellites_visible), fix_type=float(m.fix_type))


def truth_row(m, alt_mode: str) -> np.ndarray:
    """HIL_STATE_QUATERNION as t_us, NED position (m), velocity (m/s), roll, pitch, yaw (rad)."""
    x, y = latlon_to_ned(np.array([m.lat * 1e-7]), np.array([m.lon * 1e-7]))
    z = m.alt * 1e-3 if alt_mode == "ned_z" else HOME_ALT - m.alt * 1e-3
    eul = euler_from_quat(np.array([m.attitude_quaternion], dtype=float))[0]
    return np.array([m.time_usec, x[0], y[0], z, m.vx * 0.01, m.vy * 0.01, m.vz * 0.01, *eul])


class Bridge:
    """Flies ``autopilot`` against the simulator behind ``link``.

    ``truth_interval_us``: how often the simulator is asked for HIL_STATE_QUATERNION (0: never).
    ``timeout_s``: the longest wall-clock silence of the simulator before the flight is given up.
    ``max_lag_s``: with a simulator on its own clock (not lockstep), how far the flight software may
    fall behind the simulator's sensor time before the flight is given up (a controller that answers
    late flies a different vehicle: PX4 reports the same as a lost lockstep); None: not checked.
    """

    def __init__(self, link: SimLink, autopilot: HilAutopilot, truth_interval_us: int = 20000,
                 timeout_s: float = 10.0, keep_inputs: bool = True, max_lag_s: float | None = None):
        self.link = link
        self.ap = autopilot
        self.truth_interval_us = int(truth_interval_us)
        self.timeout_s = timeout_s
        self.keep_inputs = keep_inputs
        self.max_lag_s = max_lag_s
        #: the largest lag measured in the last :meth:`fly` (s; only with ``max_lag_s``)
        self.worst_lag_s = 0.0

    def fly(self, max_s: float = 150.0, first_timeout_s: float = 30.0, alive=None) -> HilFlight:
        """Run until the vehicle has landed (and ``TAIL_S`` more), crashed, or ``max_s`` of simulated time."""
        ap, link = self.ap, self.link
        pending = link.wait_first(first_timeout_s, alive)
        link.heartbeat(ap.armed)  # the simulator has spoken: it hears the flight controller at once
        if self.truth_interval_us > 0:
            link.request_truth(self.truth_interval_us)
        wall0 = time.monotonic()
        gps: GpsSample | None = None
        truth: list[np.ndarray] = []
        inputs: list[tuple[SensorSample, GpsSample | None]] = []
        outputs: list[np.ndarray] = []
        max_steps, tail = int(max_s / 0.004), int(TAIL_S / 0.004)
        landed_at, status = -1, "timeout"
        last_msg = time.monotonic()
        self.worst_lag_s = 0.0
        while ap.step_index < max_steps:
            msgs = pending or link.receive(0.5)
            pending = []
            now = time.monotonic()
            if not msgs:
                if alive is not None and not alive():
                    raise HilError("the simulator ended during the flight")
                if now - last_msg > self.timeout_s:
                    raise HilError(f"the simulator stopped sending (no message for {self.timeout_s:g} s)")
                link.heartbeat(ap.armed)
                continue
            last_msg = now
            # the lag: how much sensor time already waits behind the sample being flown (all waiting
            # messages are read at once); from 1 s on (a simulator's first messages come in a burst)
            newest = max((m.time_usec for m in msgs if m.get_type() == "HIL_SENSOR"), default=0)
            for m in msgs:
                kind = m.get_type()
                if kind == "HIL_GPS":
                    gps = gps_sample(m)
                elif kind == "HIL_STATE_QUATERNION":
                    truth.append(np.append(truth_row(m, ap.profile.truth_alt), [ap.step_index, ap.armed]))
                elif kind == "HIL_SENSOR":
                    s = sensor_sample(m)
                    if self.max_lag_s is not None and ap.step_index >= 250:
                        lag = (newest - s.t_us) * 1e-6
                        self.worst_lag_s = max(self.worst_lag_s, lag)
                        if lag > self.max_lag_s:
                            raise HilError(f"the flight software fell {lag * 1e3:.0f} ms behind the simulator's "
                                           f"real-time clock at {ap.step_index * 0.004:.1f} s (at most "
                                           f"{self.max_lag_s * 1e3:.0f} ms): fly in lockstep, or on a less "
                                           "loaded machine")
                    controls = ap.step(s, gps)
                    if self.keep_inputs:
                        inputs.append((s, gps))
                    outputs.append(controls.copy())
                    gps = None
                    link.actuators(s.t_us, controls, ap.armed)
            if now - link.last_heartbeat > 0.3:
                link.heartbeat(ap.armed)
            if landed_at < 0 and ap.landed:
                landed_at, status = ap.step_index, "landed"
            if truth and _crashed(truth[-1]):
                status = "crashed"
                break
            if landed_at >= 0 and ap.step_index >= landed_at + tail:
                break
        link.heartbeat(False)
        wall = time.monotonic() - wall0
        est = np.vstack(ap.estimate) if ap.estimate else np.zeros((0, 6))
        return HilFlight(autopilot=ap, status=status, steps=ap.step_index, wall_s=wall,
                         truth=np.vstack(truth) if truth else np.zeros((0, 12)), estimate=est, inputs=inputs,
                         outputs=np.vstack(outputs) if outputs else np.zeros((0, 4)))


def _crashed(row: np.ndarray) -> bool:
    return bool(abs(row[7]) > CRASH_TILT_RAD or abs(row[8]) > CRASH_TILT_RAD)


def replay(inputs: list[tuple[SensorSample, GpsSample | None]], autopilot: HilAutopilot) -> np.ndarray:
    """Feed recorded sensor samples to ``autopilot``; the (steps, 4) motor commands it answers with."""
    return np.vstack([autopilot.step(s, g).copy() for s, g in inputs]) if inputs else np.zeros((0, 4))
