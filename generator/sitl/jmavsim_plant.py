"""The sitl's plant with jMAVSim as its physics: ``scart-bench sitl --physics jmavsim``.

::

    jMAVSim --HIL_SENSOR, HIL_GPS--> [sensor point] --> estimator --telemetry--> (the sitl: link point, client,
    commander) --setpoint--> cascade --HIL_ACTUATOR_CONTROLS--> jMAVSim
    jMAVSim --HIL_STATE_QUATERNION--> the truth

:class:`JmavsimPlant` has the interface :class:`~scart_bench.generator.sitl.server.SitlServer` steps
(:class:`~scart_bench.generator.sitl.plant.Plant`'s): each :meth:`~JmavsimPlant.step` waits for jMAVSim's
next HIL_SENSOR, runs the project's estimator on it (the bridge's
:class:`~scart_bench.generator.hil.autopilot.HilAutopilot`, tuned for jMAVSim's airframe) and returns the
telemetry; :meth:`~JmavsimPlant.control` takes the commander's setpoint; :meth:`~JmavsimPlant.finish_step`
sends the cascade's motor commands back. With jMAVSim in lockstep (as it is started here) the sitl's clock
drives the simulator: real time, ``--speed`` or ``--lockstep``.
"""

from __future__ import annotations

import collections
import time
from types import SimpleNamespace

import numpy as np

from scart_bench.dataset.schema import TELEMETRY_TOPICS, TOPICS
from scart_bench.generator.hil.autopilot import HilAutopilot, SensorSample
from scart_bench.generator.hil.bridge import gps_sample, sensor_sample, truth_row
from scart_bench.generator.hil.errors import HilError
from scart_bench.generator.hil.jmavsim import DEFAULT_SPEED, JMavSim
from scart_bench.generator.hil.link import open_link
from scart_bench.generator.hil.profiles import JMAVSIM, SimProfile
from scart_bench.generator.params import DT, NAV_RATE_HZ, STEP_US
from scart_bench.generator.physics.rotation import euler_from_quat
from scart_bench.generator.sitl.plant import Plant, is_due
from scart_bench.generator.telemetry.schedule import FCSnapshot, compose

#: the injection points a sitl with jMAVSim physics carries (jMAVSim owns the physics: no environment, vehicle)
JMAVSIM_POINTS = ("link", "command", "sensor")
#: how often jMAVSim is asked for its ground truth (µs): the sitl's truth rate, 50 Hz
TRUTH_INTERVAL_US = 20000
#: truth z (NED, m) at or below which the vehicle counts as on the ground (jMAVSim's ground is z = 0)
GROUND_Z = -0.05


class _SensorHook:
    """The sitl's sensor hook where HilAutopilot calls its layer at the sensor point."""

    def __init__(self, hook):
        self.hook = hook

    def on_messages(self, point, k, t_us, msgs):
        return self.hook(msgs)


class SitlAutopilot(HilAutopilot):
    """The bridge's estimator and cascade with the sitl's commander in the place of its navigator.

    :meth:`sense` takes one sample (sensor point, estimator), :meth:`telemetry` composes what is due,
    :meth:`control` takes the commander's setpoint at 50 Hz, :meth:`finish` returns the motor commands.
    """

    def __init__(self, profile: SimProfile = JMAVSIM, **kwargs):
        super().__init__(np.zeros((1, 3)), 1.0, profile, **kwargs)  # the navigator is not flown
        self._gps_now: np.ndarray | None = None

    def _gps_row(self) -> np.ndarray:
        return self._gps_now

    def sense(self, s: SensorSample, gps, hook=None) -> None:
        """One sample through the sensor point (``hook``, the sitl's) into the estimator."""
        k = self.step_index
        msgs = self.sensor_messages(s, gps)
        accel, gyro = msgs["sensor_accel"], msgs["sensor_gyro"]
        mag_due, baro_due = "sensor_mag" in msgs, "sensor_baro" in msgs
        ok: dict = {}
        if hook is not None:
            self.layer = _SensorHook(hook)  # where HilAutopilot._sensor_point calls its layer
            ok = self._sensor_point(k, k * STEP_US, msgs)
            accel, gyro = ok.pop("_imu")
        self._gps_now = msgs.get("sensor_gps")
        self._estimate(k, k * DT, accel, gyro, mag_due, baro_due, gps is not None, ok)

    def telemetry(self) -> dict[str, np.ndarray]:
        """The telemetry due at this step (1, n_fields) per topic, as the built-in plant composes it."""
        due = [tp for tp in TELEMETRY_TOPICS if is_due(TOPICS[tp].rate_hz, self.step_index)]
        if not due:
            return {}
        pos, vel = self.est.output(self.es)
        snap = FCSnapshot(quat=self.es.quat, rates=self.es.rates, pos=pos, vel=vel, accel=self.accel,
                          gyro=self.gyro, mag=self.mag, pressure=self.pressure, baro_temp=self.baro_temp,
                          gps=self.gps, battery=self.battery, baro_home_alt=self.es.baro_offset)
        return {tp: compose(tp, snap) for tp in due}

    def control(self, setpoint: np.ndarray | None) -> None:
        """Velocity control and the land detector with ``setpoint`` (1, 6) vx, vy, vz, yaw, seq, armed
        (None: keep the last one; before any, hover disarmed at the current heading)."""
        if setpoint is not None:
            self.setpoint = setpoint
        elif not self.setpoint.any():
            self.setpoint[0, 3] = euler_from_quat(self.es.quat)[0, 2]
        sp, cs = self.setpoint, self.cs
        cs.armed = (sp[:, 5] > 0.5) & ~cs.disarmed_after_flight
        _, vel = self.est.output(self.es)
        self.ctrl.velocity_control(cs, sp[:, 0:3], sp[:, 3], vel, self._rot(), 1.0 / NAV_RATE_HZ)
        self.ctrl.land_detector(cs, sp[:, 0:3], vel, 1.0 / NAV_RATE_HZ)

    def finish(self) -> np.ndarray:
        """Attitude and rate control, the battery; the four motor commands (0..1) of this step."""
        self.ctrl.attitude_control(self.cs, self._rot())
        rotor = self.ctrl.rate_control(self.cs, self.es.rates)
        self.controls = self.profile.controls(rotor[0])
        self._battery(self.step_index)
        self.step_index += 1
        return self.controls

    @property
    def position_valid(self) -> bool:
        """GPS has set the origin and the pre-arm wait after it has passed (the bridge's start rule)."""
        return self.origin_s is not None and self.step_index * DT >= self.origin_s + self.start.arm_after_s


class JmavsimPlant:
    """A jMAVSim vehicle flown by the project's estimator and cascade, stepped by the sitl at 250 Hz.

    ``address``: a running simulator (``udp:HOST:PORT``, ``tcp:HOST:PORT``, ``udp-listen:HOST:PORT``,
    ``tcp-listen:HOST:PORT``, as ``generate --sim``); None starts jMAVSim from ``jar`` (a jar, its build folder,
    or ``$SCART_JMAVSIM``) headless and in lockstep, ``speed`` times faster than real time at most.
    :meth:`start` reaches the simulator (a one-line HilError when Java, the jar or its first message is
    missing); :meth:`close` ends the link and the jMAVSim it started. ``timeout_s``: the longest silence of
    the simulator during the flight.
    """

    points = JMAVSIM_POINTS
    name = "jmavsim"
    # the built-in plant's arming rules: they touch only the controller state ``cs``, which is the same here
    set_armed = Plant.set_armed
    landed_by_detector = Plant.landed_by_detector
    armed = Plant.armed

    def __init__(self, address: str | None = None, jar=None, seed: int = 0, speed: float = DEFAULT_SPEED,
                 profile: SimProfile = JMAVSIM, first_timeout_s: float = 30.0, timeout_s: float = 10.0):
        self.address = address
        self.jar = jar
        self.seed = int(seed)
        self.speed = float(speed)
        self.profile = profile
        self.first_timeout_s = float(first_timeout_s)
        self.timeout_s = float(timeout_s)
        self.ap = SitlAutopilot(profile)
        self.cs, self.es = self.ap.cs, self.ap.es
        #: jMAVSim's wind is its own (none by default); recorded as zero
        self.wind = SimpleNamespace(mean=np.zeros((1, 3)))
        self.sim: JMavSim | None = None
        self.link = None
        self._pending: collections.deque = collections.deque()
        self._gps = None
        self._truth: np.ndarray | None = None
        self.truth_rows = 0
        self._sample_us = 0

    # -- start and stop ---------------------------------------------------------------------------
    def start(self) -> JmavsimPlant:
        """Start jMAVSim (when no address was given) and wait for its first message."""
        try:
            if self.address is None:
                self.sim = JMavSim(self.jar, speed=self.speed).start()
            self.link = open_link(self.address or self.sim.link_address)
            alive = self.sim.alive if self.sim is not None else None
            self._pending.extend(self.link.wait_first(self.first_timeout_s, alive))
        except HilError as exc:
            said = f" (jMAVSim said: {self.sim.last_line()})" if self.sim is not None else ""
            self.close()
            raise HilError(f"{exc}{said}") from None
        self.link.heartbeat(False)
        self.link.request_truth(TRUTH_INTERVAL_US)
        return self

    def where(self) -> str:
        """The simulator in words, for the sitl's first line."""
        if self.sim is not None:
            return f"jMAVSim {self.sim.jar} (pid {self.sim.proc.pid}, {self.sim.link_address}, lockstep)"
        return f"the simulator at {self.address}"

    def close(self) -> None:
        if self.link is not None:
            try:
                self.link.heartbeat(False)
            except (OSError, HilError):
                pass
            self.link.close()
            self.link = None
        if self.sim is not None:
            self.sim.stop()
            self.sim = None

    def __enter__(self) -> JmavsimPlant:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def idle(self) -> None:
        """Keep the simulator's link alive while the sitl holds its clock (jMAVSim resets after 3 s of silence)."""
        if self.link is not None and time.monotonic() - self.link.last_heartbeat > 0.3:
            self.link.heartbeat(self.armed)

    # -- the sitl's step --------------------------------------------------------------------------
    @property
    def step_index(self) -> int:
        return self.ap.step_index

    @property
    def t_us(self) -> int:
        """Time of the step about to run (µs since boot)."""
        return self.ap.step_index * STEP_US

    @property
    def battery(self) -> np.ndarray:
        return self.ap.battery

    def step(self, env=None, sensor_hook=None) -> dict[str, np.ndarray]:
        """Wait for jMAVSim's next HIL_SENSOR (and the HIL_GPS before it), estimate; the telemetry due.
        ``env`` must be None (jMAVSim owns the physics); ``sensor_hook`` is the sitl's sensor point."""
        if env is not None:
            raise HilError("environment and vehicle scenarios need the built-in physics, not jMAVSim's")
        sample = self._next_sensor()
        gps, self._gps = self._gps, None
        self.ap.sense(sample, gps, sensor_hook)
        return self.ap.telemetry()

    def control(self, setpoint: np.ndarray | None) -> None:
        self.ap.control(setpoint)

    def finish_step(self) -> np.ndarray | None:
        """Send the motor commands (which, in lockstep, lets jMAVSim step); the truth row (1, 11) at 50 Hz."""
        k = self.ap.step_index
        controls = self.ap.finish()
        link = self.link
        link.actuators(self._sample_us, controls, self.armed)
        if time.monotonic() - link.last_heartbeat > 0.3:
            link.heartbeat(self.armed)
        if not is_due(50.0, k) or self._truth is None:
            return None
        t = self._truth
        on_ground = float(t[3] >= GROUND_Z)
        return np.array([[*t[1:10], float(self.armed), on_ground]])

    def _next_sensor(self) -> SensorSample:
        if self.link is None:
            raise HilError("the jMAVSim plant was not started (JmavsimPlant.start)")
        last = time.monotonic()
        while True:
            while self._pending:
                m = self._pending.popleft()
                kind = m.get_type()
                if kind == "HIL_SENSOR":
                    s = sensor_sample(m)
                    self._sample_us = s.t_us
                    return s
                if kind == "HIL_GPS":
                    self._gps = gps_sample(m)
                elif kind == "HIL_STATE_QUATERNION":
                    self._truth = truth_row(m, self.profile.truth_alt)
                    self.truth_rows += 1
            msgs = self.link.receive(0.5)
            now = time.monotonic()
            if msgs:
                self._pending.extend(msgs)
                last = now
                continue
            if self.sim is not None and not self.sim.alive():
                raise HilError(f"jMAVSim ended during the flight (it said: {self.sim.last_line()})")
            if now - last > self.timeout_s:
                raise HilError(f"the simulator ({self.link.where()}) stopped sending (no message for "
                               f"{self.timeout_s:g} s)")
            self.link.heartbeat(self.armed)

    # -- what the flight controller knows about itself --------------------------------------------
    @property
    def position(self) -> np.ndarray:
        """Estimated NED position (3,)."""
        return self.ap.est.output(self.es)[0][0].copy()

    @property
    def velocity(self) -> np.ndarray:
        return self.ap.est.output(self.es)[1][0].copy()

    @property
    def yaw(self) -> float:
        return float(euler_from_quat(self.es.quat)[0, 2])

    @property
    def position_valid(self) -> bool:
        return self.ap.position_valid
