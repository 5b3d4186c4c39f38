"""Sensor models with PX4 Gazebo-classic defaults: IMU, magnetometer, barometer and GPS.

Each model turns the true vehicle state into what the flight controller's estimator receives.
Noise comes from the per-flight NoiseStream slice handed to each call.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scart_bench.dataset.schema import HOME_ALT
from scart_bench.generator.geo import pressure_at
from scart_bench.generator.params import GRAVITY, SensorParams
from scart_bench.generator.physics.disturbances import Disturbances, gps_signal_quality
from scart_bench.generator.physics.rotation import rotate_t

#: satellites used at the fix: this many fewer than the receiver settles on; one more per second
SATS_RAMP = 3.0
#: reported accuracy at the fix is (1 + EPH_SETTLE) times the settled one, decaying with EPH_SETTLE_TAU_S
EPH_SETTLE = 0.5
EPH_SETTLE_TAU_S = 6.0


def gps_quality(t: float, fix_s: np.ndarray, sats_settled: np.ndarray, sats_now: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(fixed, satellites used, accuracy scale) of the receivers at time ``t`` (s).

    ``sats_now``: the satellites the receiver could use now (fewer under jamming). Before its fix
    a receiver has no fix; from the fix its count climbs one a second from ``SATS_RAMP`` fewer than
    ``sats_settled``, and its eph / epv are (1 + ``EPH_SETTLE``) times the settled ones, shrinking.
    """
    since = t - np.asarray(fix_s, dtype=float)
    fixed = since >= 0.0
    after = np.maximum(since, 0.0)
    cap = np.asarray(sats_settled, dtype=float) - SATS_RAMP + np.floor(after)
    sats = np.maximum(np.minimum(np.asarray(sats_now, dtype=float), cap), 0.0)
    scale = 1.0 + EPH_SETTLE * np.exp(-after / EPH_SETTLE_TAU_S)
    return fixed, sats, scale


@dataclass
class SensorState:
    """Slowly varying sensor errors of a batch (leading flight axis)."""

    accel_bias: np.ndarray  # (N, 3) m/s^2
    gyro_bias: np.ndarray  # (N, 3) rad/s
    baro_offset: np.ndarray  # (N,) Pa
    gps_bias: np.ndarray  # (N, 3) m, NED: the receiver's slow error
    gps_drive: np.ndarray  # (N, 3) m: the Gauss-Markov process the slow error lags behind (gps_error_coefficients)
    satellites: np.ndarray  # (N,) satellites in view
    truth_buffer: np.ndarray  # (delay_steps, N, 6) true pos/vel, for the GPS delay
    temperature: np.ndarray  # (N,) degC
    last_fix: np.ndarray | None = None  # (N, 3) last fixed position, reported while the fix is lost
    fix_at: np.ndarray | None = None  # (N,) s, the receiver's first fix (generator.flight_software.startup); None: from boot
    #: (2, N, 6) state of the IMU noise's low-pass (accelerometer x/y/z, gyro x/y/z; SensorParams.*_noise_cutoff_hz)
    imu_lowpass: np.ndarray | None = None
    baro_lowpass: np.ndarray | None = None  # (2, N) the baro noise's
    #: (N, 3) rad/s, the body rates of the IMU's last sample: its angular acceleration (SensorParams.imu_offset_m)
    prev_omega: np.ndarray | None = None
    #: (N, 6) how hard each flight's vehicle shakes its IMU: accelerometer x/y/z, gyro x/y/z multiples of the
    #: vibration (SensorParams.vibration_levels, :func:`flight_vibration_levels`); None: 1
    vibration_level: np.ndarray | None = None
    #: (N, 6) the IMU's noise draws of the last sample (accelerometer x/y/z, gyro x/y/z): a rough vehicle's
    #: high-frequency vibration is their difference (SensorParams.vibration_levels)
    prev_draw: np.ndarray | None = None
    #: (N, 6) a rough vehicle's high-frequency vibration of the last sample, accelerometer x/y/z and gyro x/y/z: in
    #: the logged IMU only (:func:`logged_imu`), the flight controller's filters take it out
    imu_hf: np.ndarray | None = None
    #: (2, N) Pa, the baro's slow error and its drive (SensorParams.baro_wander_pa; :func:`baro_wander_coefficients`)
    baro_wander: np.ndarray | None = None
    #: (N,) m/s, the true horizontal speed of the last step (:meth:`Sensors.push_truth`; SensorParams.baro_speed_pa)
    speed: np.ndarray | None = None


def gps_error_coefficients(p: SensorParams, dt_gps: float) -> tuple[float, np.ndarray]:
    """(a, c): the receiver's slow error is smooth, a first-order lag of a Gauss-Markov drive
    (both with time constant ``gps_bias_tau``: drive <- a drive + c w, error <- a error + (1 - a) drive).

    A plain Gauss-Markov error steps by ~sqrt(2 dt / tau) sigma at every fix (1.7 cm per 0.1 s at
    0.3 m, 60 s): the estimator read those steps as 0.17 m/s of velocity noise and the vehicle
    leaned after them (roll/pitch at hover 6x the SIL log's, docs/realism.md). A receiver's error
    is smooth from fix to fix. ``c`` makes the error's stationary sigma ``gps_bias_h`` / ``_v``:
    the lag's variance is (1 + a^2) / (1 + a)^2 of its drive's."""
    a = float(np.exp(-dt_gps / p.gps_bias_tau))
    scale = np.array([p.gps_bias_h, p.gps_bias_h, p.gps_bias_v])
    return a, np.sqrt(1 - a * a) * (1 + a) / np.sqrt(1 + a * a) * scale


def baro_wander_coefficients(p: SensorParams) -> tuple[float, float]:
    """(a, c) of the baro's slow error (``baro_wander_pa``, ``baro_wander_tau_s``): a first-order lag of a
    Gauss-Markov drive, as the GPS's slow error (:func:`gps_error_coefficients`), per baro sample: drive <- a drive
    + c w, wander <- a wander + (1 - a) drive, a = exp(-1 / (rate tau)), ``c`` making the wander's stationary sigma
    ``baro_wander_pa``. Smooth: its power falls as f^-4 above 1 / (2 pi tau), so it moves the baro below 0.5 Hz and
    leaves its sample-to-sample noise as it was (a plain Gauss-Markov error's steps add to it). Driven by the baro's
    own draw ``w`` (no new random numbers): the baro's error is one coloured noise. (1, 0) when off."""
    if not p.baro_wander_pa > 0.0:
        return 1.0, 0.0
    a = float(np.exp(-1.0 / (p.baro_rate_hz * max(p.baro_wander_tau_s, 1e-6))))
    return a, float(p.baro_wander_pa * np.sqrt(1.0 - a * a) * (1.0 + a) / np.sqrt(1.0 + a * a))


#: m/s of horizontal speed up to which the baro has no noise of forward flight. The ArduCopter fleet's 10 s windows
#: below 0.5 m/s are as quiet as its hover, and their sample-to-sample baro noise grows from there to 2-3 m/s (then
#: stays: 16 m/s is as loud); the generated flights' hover windows move faster than the fleet's (median 0.60 against
#: 0.48 m/s), and from 0.5 m/s the noise reached them (hover baro std of differences x1.15 -> x1.26 the fleet's)
BARO_FLOW_FROM = 1.0


def baro_flow(p: SensorParams, speed) -> np.ndarray | float:
    """The baro's noise in forward flight (Pa per sample): ``baro_speed_pa`` times the horizontal ``speed`` above
    :data:`BARO_FLOW_FROM`, over ``baro_speed_full_m_s`` less it, between 0 and 1. The compiled kernel has the same
    lines."""
    ramp = (np.asarray(speed) - BARO_FLOW_FROM) * (1.0 / (p.baro_speed_full_m_s - BARO_FLOW_FROM))
    return p.baro_speed_pa * np.minimum(np.maximum(ramp, 0.0), 1.0)


def lowpass_coefficients(cutoff_hz: float, rate_hz: float) -> np.ndarray | None:
    """(b0, b1, b2, a1, a2) of a second-order Butterworth low-pass at ``cutoff_hz`` of a ``rate_hz`` series
    (as ArduPilot's LowPassFilter2p and PX4's gyro and accelerometer filters), scaled so that unit white
    noise in gives unit variance out: a noise of sigma per sample keeps sigma per sample, coloured. None for
    a cutoff of 0 (white noise, the samples as drawn). A cutoff at or above 0.45 x ``rate_hz`` is taken as
    0.45 x ``rate_hz`` (a Butterworth design needs it below the Nyquist frequency)."""
    from scipy import signal

    if not cutoff_hz > 0.0:
        return None
    b, a = signal.butter(2, min(float(cutoff_hz), 0.45 * rate_hz), fs=rate_hz)
    h = signal.lfilter(b, a, np.r_[1.0, np.zeros(int(40 * rate_hz / min(cutoff_hz, 0.45 * rate_hz)) + 200)])
    gain = 1.0 / float(np.sqrt(np.dot(h, h)))
    return np.array([b[0] * gain, b[1] * gain, b[2] * gain, a[1], a[2]])


def lowpass_step(c: np.ndarray, z: np.ndarray, x: np.ndarray) -> np.ndarray:
    """One sample of the low-pass ``c`` (:func:`lowpass_coefficients`) on ``x``; ``z`` (2, ...) is its state
    (transposed direct form II), updated in place. The compiled kernel has the same lines."""
    y = c[0] * x + z[0]
    z[0] = c[1] * x - c[3] * y + z[1]
    z[1] = c[2] * x - c[4] * y
    return y


def lowpass_lag1(cutoff_hz: float, rate_hz: float, every: int = 1) -> tuple[float, float]:
    """The lag-1 autocorrelation of low-passed white noise (:func:`lowpass_coefficients`) read every
    ``every`` samples, and of its first differences: what a log at ``rate_hz / every`` shows of it
    (white: 0 and -0.5)."""
    c = lowpass_coefficients(cutoff_hz, rate_hz)
    if c is None:
        return 0.0, -0.5
    from scipy import signal

    n = int(40 * rate_hz / min(cutoff_hz, 0.45 * rate_hz)) + 200 + 2 * every
    h = signal.lfilter(c[:3], np.r_[1.0, c[3:]], np.r_[1.0, np.zeros(n)])
    r = [float(np.dot(h[:len(h) - k], h[k:]) / np.dot(h, h)) for k in (every, 2 * every)]
    return r[0], (2 * r[0] - 1 - r[1]) / (2 * (1 - r[0]))


#: a vehicle's vibration level (SensorParams.vibration_levels) up to which its vibration is the fleet's kind (white or
#: low-passed, as calibrated); the rest is high-frequency. At 2.5 x the fitted gyro vibration low-passed at 3 Hz the
#: ArduCopter fleet's fastest mission's roll std grows 0.15 -> 0.20 rad; at 5 x, 3 of 4 flights time out
VIB_AS_FLEET = 1.0
#: 1 / sqrt 2: the difference of two unit draws has unit variance (a rough vehicle's high-frequency vibration)
HF_NORM = 0.7071067811865476
#: rotor speed, as a fraction of the hover speed, from which the motors shake the IMU fully
VIBRATION_FULL_FROM = 0.3


def vibration_scale(rotor_speed: np.ndarray, hover_rotor_speed: float) -> np.ndarray:
    """(N,) how hard the motors shake the IMU, 1 at hover: none with the motors stopped, rising with
    their mean speed to 1 from VIBRATION_FULL_FROM of the hover speed (idle on the ground: 0.39),
    then as the speed. The ArduCopter logs' vibration armed on the ground is 0.8-1.6x their hover's
    (sample-to-sample accelerometer noise, perf.realism_tells): a frame on its legs shakes as much
    at idle as in the air."""
    r = np.asarray(rotor_speed).mean(axis=1) * (1.0 / hover_rotor_speed)
    return np.maximum(np.minimum(r / VIBRATION_FULL_FROM, 1.0), r)


def thrust_scale(rotor_speed: np.ndarray, hover_rotor_speed: float) -> np.ndarray:
    """(N,) the rotors' thrust over the hover thrust (mean of the squared speeds over the hover speed's square):
    how hard the downwash stirs the baro (SensorParams.baro_downwash_pa); about 0.15 at idle, 0 stopped."""
    return np.mean(np.asarray(rotor_speed) ** 2, axis=1) * (1.0 / (hover_rotor_speed * hover_rotor_speed))


def flight_vibration_levels(levels, seeds) -> np.ndarray | None:
    """(N, 6) the accelerometer x/y/z and gyro x/y/z vibration multiples of the flights with ``seeds``: flight with
    seed s takes ``levels[s mod len(levels)]`` (SensorParams.vibration_levels); None for no levels (every flight 1)."""
    if not levels:
        return None
    table = np.asarray(levels, dtype=float).reshape(len(levels), 6)
    return table[[int(s) % len(levels) for s in seeds]]


def logged_imu(st: SensorState, accel: np.ndarray, gyro: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The IMU sample as the flight's log and telemetry carry it: ``accel`` / ``gyro`` (what the flight controller
    uses) plus a rough vehicle's high-frequency vibration (``st.imu_hf``; SensorParams.vibration_levels)."""
    if st.imu_hf is None:
        return accel, gyro
    return accel + st.imu_hf[:, 0:3], gyro + st.imu_hf[:, 3:6]


def lever_arm(omega: np.ndarray, alpha: np.ndarray, r: np.ndarray) -> np.ndarray:
    """(N, 3) what an accelerometer at ``r`` (m, body frame) reads beyond the centre of gravity's specific force:
    alpha x r + omega x (omega x r), the body rates ``omega`` (rad/s) and their rate of change ``alpha`` (rad/s^2).
    The compiled kernel has the same lines."""
    w0, w1, w2 = omega[:, 0], omega[:, 1], omega[:, 2]
    c0 = w1 * r[2] - w2 * r[1]
    c1 = w2 * r[0] - w0 * r[2]
    c2 = w0 * r[1] - w1 * r[0]
    return np.column_stack([alpha[:, 1] * r[2] - alpha[:, 2] * r[1] + (w1 * c2 - w2 * c1),
                            alpha[:, 2] * r[0] - alpha[:, 0] * r[2] + (w2 * c0 - w0 * c2),
                            alpha[:, 0] * r[1] - alpha[:, 1] * r[0] + (w0 * c1 - w1 * c0)])


class Sensors:
    """All sensors of a batch of vehicles; call the sample methods at their own rates."""

    def __init__(self, params: SensorParams, dt: float):
        self.params = params
        self.dt = dt
        self.delay_steps = max(1, int(round(params.gps_delay_s / dt)))
        self.mag_field = np.array(params.mag_field_ned)
        rate = 1.0 / dt
        self.accel_lowpass = lowpass_coefficients(params.accel_noise_cutoff_hz, rate)
        self.gyro_lowpass = lowpass_coefficients(params.gyro_noise_cutoff_hz, rate)
        self.baro_lowpass = lowpass_coefficients(params.baro_noise_cutoff_hz, params.baro_rate_hz)

    def init_state(self, n: int, rngs: list[np.random.Generator]) -> SensorState:
        p = self.params
        u = np.array([g.standard_normal(12) for g in rngs])  # (N, 12)
        return SensorState(
            accel_bias=0.02 * u[:, 0:3],
            gyro_bias=0.002 * u[:, 3:6],
            baro_offset=p.baro_drift_pa * u[:, 6],
            gps_bias=(bias := np.column_stack([p.gps_bias_h * u[:, 7], p.gps_bias_h * u[:, 8], p.gps_bias_v * u[:, 9]])),
            gps_drive=bias.copy(),
            satellites=np.clip(np.round(12 + 1.5 * u[:, 10]), 8, 16),
            truth_buffer=np.zeros((self.delay_steps, n, 6)),
            temperature=20.0 + 3.0 * u[:, 11],
            imu_lowpass=np.zeros((2, n, 6)), baro_lowpass=np.zeros((2, n)),
        )

    def imu(self, st: SensorState, accel_ned: np.ndarray, omega: np.ndarray, R: np.ndarray,
            noise: np.ndarray, vibration: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Accelerometer (specific force, FRD) and gyro samples; advances the bias random walks.

        ``vibration`` (N,): the rotors' mean speed over their hover speed (:func:`vibration_scale`);
        the motors shake the accelerometer by ``accel_vibration`` and the gyro by ``gyro_vibration``
        times it (white, as the sensor's own noise: one draw of their combined sigma), none with the
        motors stopped. With ``accel_noise_cutoff_hz`` / ``gyro_noise_cutoff_hz`` the vibration is low-passed
        (:func:`lowpass_coefficients`: the same sigma per sample, coloured; the same draws, so no new random
        numbers) and the sensor's own noise stays white: a frame's shaking and rocking is coloured, the
        firmware-filtered sensor noise at a log's 50 Hz is not (the ArduCopter fleet's gyro on the ground).

        With ``vibration_levels`` (``st.vibration_level``), each flight's vehicle shakes its accelerometer and gyro
        that many times as hard, per axis (a level below 1 scales the vibration down): up to :data:`VIB_AS_FLEET`
        times the vibration as above, a rougher vehicle's rest (in squares) at high frequency, the difference of this sample's draws and the last's
        / sqrt 2 (unit variance, no power at 0 Hz; white at a log's 50 Hz), kept in ``st.imu_hf`` for the logged IMU
        (:func:`logged_imu`) and not returned: a propeller's shaking is at tens to hundreds of Hz, which the flight
        controller's gyro and accelerometer filters take out (ArduCopter's INS_GYRO_FILTER 20 Hz) while its log's
        IMU samples carry it. Fed to the controller, noise of that size saturates the mixer and is integrated into
        tilts the vehicle flies (a 2 m/s mission flown at 20 m/s, timing out).

        With ``imu_offset_m`` the accelerometer sits that far from the centre of gravity and reads the rocking's
        :func:`lever_arm` too, the angular acceleration being the change of ``omega`` since the last call."""
        p, dt = self.params, self.dt
        fs = rotate_t(R, accel_ned - np.array([0.0, 0.0, GRAVITY]))
        if any(p.imu_offset_m):
            if st.prev_omega is None:
                st.prev_omega = np.zeros_like(omega)
            fs = fs + lever_arm(omega, (omega - st.prev_omega) / dt, np.asarray(p.imu_offset_m, dtype=float))
            st.prev_omega = np.array(omega, dtype=float)
        a_ab = np.exp(-dt / p.accel_bias_tau)
        a_gb = np.exp(-dt / p.gyro_bias_tau)
        st.accel_bias = a_ab * st.accel_bias + p.accel_bias_random_walk * np.sqrt(dt) * noise[:, 6:9]
        st.gyro_bias = a_gb * st.gyro_bias + p.gyro_bias_random_walk * np.sqrt(dt) * noise[:, 9:12]
        acc_sigma = p.accel_noise_density * np.sqrt(1 / dt) * np.array([1.0, 1.0, p.accel_noise_z_factor])
        gyro_sigma = p.gyro_noise_density * np.sqrt(1 / dt)
        w_acc, w_gyro = noise[:, 0:3], noise[:, 3:6]
        acc_noise, gyro_noise = acc_sigma * w_acc, gyro_sigma * w_gyro
        if vibration is not None:
            vib_a = vib_g = np.asarray(vibration)[:, None]
            hf = None
            if st.vibration_level is not None:  # each vehicle's own (SensorParams.vibration_levels)
                la, lg, c2 = st.vibration_level[:, 0:3], st.vibration_level[:, 3:6], VIB_AS_FLEET * VIB_AS_FLEET
                extra_a = vib_a * np.sqrt(np.maximum(la * la - c2, 0.0)) * np.array(p.accel_vibration)
                extra_g = vib_g * np.sqrt(np.maximum(lg * lg - c2, 0.0)) * np.array(p.gyro_vibration)
                vib_a, vib_g = vib_a * np.minimum(la, VIB_AS_FLEET), vib_g * np.minimum(lg, VIB_AS_FLEET)
                if st.prev_draw is None:
                    st.prev_draw = np.zeros_like(noise[:, 0:6])
                hf = (noise[:, 0:6] - st.prev_draw) * HF_NORM  # the draws' differences: unit variance, none at 0 Hz
                st.prev_draw = np.array(noise[:, 0:6], dtype=float)
            vib = vib_a * np.array(p.accel_vibration)
            vib_g = vib_g * np.array(p.gyro_vibration)
            if (self.accel_lowpass is not None or self.gyro_lowpass is not None) and st.imu_lowpass is None:
                st.imu_lowpass = np.zeros((2, len(fs), 6))
            if self.accel_lowpass is None:  # white: one draw of the combined sigma
                acc_noise = np.sqrt(acc_sigma * acc_sigma + vib * vib) * w_acc
            else:  # the sensor's own noise white, the vibration low-passed (the same draws)
                acc_noise = acc_noise + vib * lowpass_step(self.accel_lowpass, st.imu_lowpass[:, :, 0:3], w_acc)
            if self.gyro_lowpass is None:
                gyro_noise = np.sqrt(gyro_sigma * gyro_sigma + vib_g * vib_g) * w_gyro
            else:
                gyro_noise = gyro_noise + vib_g * lowpass_step(self.gyro_lowpass, st.imu_lowpass[:, :, 3:6], w_gyro)
            if hf is not None:  # a rougher vehicle's rest: high-frequency shaking, in the logged IMU (logged_imu)
                st.imu_hf = np.concatenate([extra_a * hf[:, 0:3], extra_g * hf[:, 3:6]], axis=1)
        acc = fs + st.accel_bias + acc_noise
        gyro = omega + st.gyro_bias + gyro_noise
        return acc, gyro

    def mag(self, R: np.ndarray, noise: np.ndarray, disturbance: np.ndarray | None = None) -> np.ndarray:
        """Magnetometer (gauss, FRD); ``disturbance`` (N, 3) is a local field added to the earth's (NED)."""
        field = np.broadcast_to(self.mag_field, (R.shape[0], 3))
        if disturbance is not None:
            field = field + disturbance
        return rotate_t(R, field) + self.params.mag_noise * noise

    def baro(self, st: SensorState, pos: np.ndarray, noise: np.ndarray, thrust: np.ndarray | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
        """Static pressure (Pa) and temperature (degC); the pressure noise low-passed with ``baro_noise_cutoff_hz``.

        With ``baro_downwash_pa``: the sensor's own noise ``baro_noise_pa`` white and the rotors' downwash on top,
        ``baro_downwash_pa`` times ``thrust`` (N,) (:func:`thrust_scale`; None: motors stopped), low-passed (the
        same draws, as the IMU's vibration)."""
        w = noise[:, 0]
        wander = 0.0
        if self.params.baro_wander_pa > 0.0:  # the slow error, on the same draws (baro_wander_coefficients)
            a, c = baro_wander_coefficients(self.params)
            if st.baro_wander is None:
                st.baro_wander = np.zeros((2, len(w)))  # the drive and the wander
            st.baro_wander[0] = a * st.baro_wander[0] + c * w
            st.baro_wander[1] = a * st.baro_wander[1] + (1.0 - a) * st.baro_wander[0]
            wander = st.baro_wander[1]
        if self.params.baro_downwash_pa > 0.0:
            own = self.params.baro_noise_pa
            amp = 0.0 if thrust is None else self.params.baro_downwash_pa * np.asarray(thrust)
            if self.params.baro_speed_pa > 0.0 and st.speed is not None:  # the noise in forward flight, in squares
                flow = baro_flow(self.params, st.speed)
                amp = np.sqrt(amp * amp + flow * flow)
            if self.baro_lowpass is not None:  # the downwash low-passed, the sensor's own noise white (the same draws)
                if st.baro_lowpass is None:
                    st.baro_lowpass = np.zeros((2, len(w)))
                noise_pa = own * w + amp * lowpass_step(self.baro_lowpass, st.baro_lowpass, w)
            else:  # white: one draw of the combined sigma
                noise_pa = np.sqrt(own * own + amp * amp) * w
            press = pressure_at(HOME_ALT - pos[:, 2]) + st.baro_offset + noise_pa + wander
            return press, st.temperature - 0.0065 * (-pos[:, 2]) + 0.05 * noise[:, 1]
        if self.baro_lowpass is not None:
            if st.baro_lowpass is None:
                st.baro_lowpass = np.zeros((2, len(w)))
            w = lowpass_step(self.baro_lowpass, st.baro_lowpass, w)
        sigma = self.params.baro_noise_pa
        if self.params.baro_speed_pa > 0.0 and st.speed is not None:  # the noise in forward flight, in squares
            flow = baro_flow(self.params, st.speed)
            sigma = np.sqrt(sigma * sigma + flow * flow)
        press = pressure_at(HOME_ALT - pos[:, 2]) + st.baro_offset + sigma * w + wander
        temp = st.temperature - 0.0065 * (-pos[:, 2]) + 0.05 * noise[:, 1]
        return press, temp

    def push_truth(self, st: SensorState, step: int, pos: np.ndarray, vel: np.ndarray) -> None:
        """Store the true state; the GPS reports it ``delay_steps`` later."""
        st.truth_buffer[step % self.delay_steps, :, :3] = pos
        st.truth_buffer[step % self.delay_steps, :, 3:] = vel
        if self.params.baro_speed_pa > 0.0:  # the baro's noise in forward flight
            st.speed = np.sqrt(vel[:, 0] * vel[:, 0] + vel[:, 1] * vel[:, 1])

    def gps(self, st: SensorState, step: int, noise: np.ndarray, dt_gps: float,
            env: Disturbances | None = None) -> dict[str, np.ndarray]:
        """GPS fix of the delayed true state: NED position (m), NED velocity, accuracies.

        ``env`` carries RF-level attacks: a spoofer's offsets (and its simulated constellation)
        and jamming, which costs satellites and accuracy and, below 4 satellites, the fix.
        """
        p = self.params
        old = st.truth_buffer[(step + 1) % self.delay_steps] if step + 1 >= self.delay_steps else st.truth_buffer[0]
        a, c = gps_error_coefficients(p, dt_gps)
        st.gps_drive = a * st.gps_drive + c * noise[:, 0:3]
        st.gps_bias = a * st.gps_bias + (1.0 - a) * st.gps_drive
        white = np.array([p.gps_noise_h, p.gps_noise_h, p.gps_noise_v]) * noise[:, 3:6]
        vel_noise = p.gps_vel_noise * noise[:, 6:9]
        sats = st.satellites
        growth = None
        if env is not None:
            sats = np.where(env.gps_spoofed, env.gps_spoof_satellites, st.satellites)
            sats, growth = gps_signal_quality(sats, env.gps_js_db)
            white = white * growth[:, None]
            vel_noise = vel_noise * growth[:, None]
        pos = old[:, :3] + st.gps_bias + white
        vel = old[:, 3:] + vel_noise
        n = pos.shape[0]
        eph = np.full(n, np.hypot(p.gps_noise_h, p.gps_bias_h)) * (12.0 / np.maximum(sats, 1.0))
        epv = np.full(n, np.hypot(p.gps_noise_v, p.gps_bias_v)) * (12.0 / np.maximum(sats, 1.0))
        fix = np.full(n, 3.0)
        settling = None
        if st.fix_at is not None:  # a receiver that starts: no fix yet, then satellites and accuracy settle
            settling, sats, scale = gps_quality(step * self.dt, st.fix_at, st.satellites, sats)
            eph = np.hypot(p.gps_noise_h, p.gps_bias_h) * (12.0 / np.maximum(sats, 1.0)) * scale
            epv = np.hypot(p.gps_noise_v, p.gps_bias_v) * (12.0 / np.maximum(sats, 1.0)) * scale
        if env is not None:
            pos = pos + env.gps_offset
            vel = vel + env.gps_vel_offset
            eph, epv = eph * growth, epv * growth
            fixed = sats >= 4
            fix = np.where(fixed, 3.0, 1.0)  # MAVLink GPS_FIX_TYPE: 3 = 3D fix, 1 = no fix
            if st.last_fix is None:
                st.last_fix = pos.copy()
            st.last_fix[fixed] = pos[fixed]
            if not fixed.all():
                lost = ~fixed
                pos[lost] = st.last_fix[lost]
                vel[lost] = 0.0
                eph[lost], epv[lost] = 99.99, 99.99
        if settling is not None and not settling.all():
            early = ~settling
            fix = np.where(early, 1.0, fix)  # MAVLink GPS_FIX_TYPE_NO_FIX until the first fix
            eph, epv = np.where(early, 99.99, eph), np.where(early, 99.99, epv)
        return {"pos": pos, "vel": vel, "eph": eph, "epv": epv, "satellites": np.asarray(sats, dtype=float).copy(),
                "fix_type": fix}
