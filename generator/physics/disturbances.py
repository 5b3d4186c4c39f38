"""Physical disturbances of one simulation step: what environment attacks and reliability faults do.

The SCART layer's ``environment`` and ``vehicle`` scenarios do not touch messages: they change the
world the flight controller lives in (wind, GPS signals, the magnetic field) or the vehicle itself
(motors, battery, sensor instances). The layer fills a ``Disturbances`` for the batch at every
step and the simulator applies it; neutral values mean "nothing acts".
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: Sensor instances a reliability fault can take out (``sensor_instance_loss``).
SENSOR_INSTANCES = ("accel", "gyro", "mag", "baro", "gps")


@dataclass
class MagneticSource:
    """A local magnetic disturbance (e.g. a power line or steel structure) for some flights."""

    rows: np.ndarray  # (k,) flights of the batch it acts on
    center_ned: np.ndarray  # (k, 3) m
    strength: np.ndarray  # (k,) gauss at ``reference_m``
    reference_m: np.ndarray  # (k,)
    direction_ned: np.ndarray  # (k, 3) unit vector of the disturbing field


@dataclass
class Jammer:
    """A GPS jammer: jammer-to-signal ratio ``js_db`` at ``reference_m`` from ``center_ned``
    (free-space loss, 20 log10 of the distance ratio), or everywhere when ``center_ned`` is None."""

    rows: np.ndarray  # (k,)
    js_db: np.ndarray  # (k,)
    center_ned: np.ndarray | None = None  # (k, 3) m
    reference_m: np.ndarray | None = None  # (k,)


@dataclass
class Disturbances:
    """Batch-wide physical effects for one step (leading flight axis)."""

    wind: np.ndarray  # (N, 3) m/s added to the wind, NED
    motor_efficiency: np.ndarray  # (N, 4) thrust multiplier per rotor
    rotor_limit: np.ndarray  # (N,) fraction of the maximum rotor speed available (battery sag)
    battery_sag_v: np.ndarray  # (N,) volts off the battery's terminal voltage
    gps_offset: np.ndarray  # (N, 3) m added to GPS fixes (RF spoofing)
    gps_vel_offset: np.ndarray  # (N, 3) m/s added to GPS velocities (RF spoofing)
    gps_spoofed: np.ndarray  # (N,) bool: the receiver tracks a spoofer's constellation
    gps_spoof_satellites: np.ndarray  # (N,) satellites the spoofer simulates
    gps_js_db: np.ndarray  # (N,) jammer-to-signal ratio at the antenna, dB (-inf: none)
    magnetic: list[MagneticSource] = field(default_factory=list)
    jammers: list[Jammer] = field(default_factory=list)
    sensor_lost: dict[str, np.ndarray] = field(default_factory=dict)  # instance -> (N,) bool
    sensor_failover: dict[str, np.ndarray] = field(default_factory=dict)  # instance -> (N,) bool
    sensor_offset: dict[str, np.ndarray] = field(default_factory=dict)  # instance -> (N,) secondary's offset

    @classmethod
    def none(cls, n: int) -> Disturbances:
        return cls(
            wind=np.zeros((n, 3)), motor_efficiency=np.ones((n, 4)), rotor_limit=np.ones(n),
            battery_sag_v=np.zeros(n), gps_offset=np.zeros((n, 3)), gps_vel_offset=np.zeros((n, 3)),
            gps_spoofed=np.zeros(n, dtype=bool), gps_spoof_satellites=np.zeros(n),
            gps_js_db=np.full(n, -np.inf),
        )

    def lost(self, sensor: str) -> np.ndarray | None:
        """Flights whose ``sensor`` instance is lost with no failover (None: none)."""
        lost = self.sensor_lost.get(sensor)
        if lost is None or not lost.any():
            return None
        return lost & ~self.sensor_failover.get(sensor, np.zeros_like(lost))

    def resolve(self, pos_ned: np.ndarray) -> None:
        """Fill the position-dependent fields (the jamming level) for the true positions."""
        if not self.jammers:
            return
        power = np.zeros(pos_ned.shape[0])  # linear J/S, summed over jammers
        for jam in self.jammers:
            js = jam.js_db
            if jam.center_ned is not None:
                d = np.linalg.norm(pos_ned[jam.rows] - jam.center_ned, axis=1)
                js = js - 20.0 * np.log10(np.maximum(d, 1.0) / jam.reference_m)
            power[jam.rows] += 10.0 ** (js / 10.0)
        with np.errstate(divide="ignore"):
            self.gps_js_db = np.where(power > 0, 10.0 * np.log10(np.where(power > 0, power, 1.0)), -np.inf)

    def magnetic_field(self, pos_ned: np.ndarray) -> np.ndarray | None:
        """(N, 3) gauss of the local disturbances at the true positions (None: none acts)."""
        if not self.magnetic:
            return None
        out = np.zeros_like(pos_ned)
        for src in self.magnetic:
            d = np.linalg.norm(pos_ned[src.rows] - src.center_ned, axis=1)
            fall = (src.reference_m / np.maximum(d, 1.0)) ** 3  # a dipole's far field falls as 1/r^3
            out[src.rows] += (src.strength * fall)[:, None] * src.direction_ned
        return out


# -- GPS signal quality under jamming --------------------------------------------------------------
#: Nominal carrier-to-noise density of the strongest and weakest tracked satellite (dB-Hz).
CN0_STRONG, CN0_WEAK = 47.0, 37.0
#: Below this C/N0 a receiver loses lock on a satellite (dB-Hz, a typical tracking threshold).
CN0_TRACKING = 27.0
#: Spectral separation of wideband noise jamming for GPS L1 C/A: Q * chip rate (1/s).
JAM_Q_RC = 1.0 * 1.023e6


def jammed_cn0(cn0_nominal: np.ndarray, js_db: np.ndarray) -> np.ndarray:
    """Effective C/N0 (dB-Hz) under a jammer-to-signal ratio ``js_db`` (the standard GNSS formula).

    C/N0_eff = -10 log10(10^(-C/N0 / 10) + 10^(J/S / 10) / (Q Rc)).
    """
    js = np.asarray(js_db, dtype=float)
    lin = np.where(np.isfinite(js), 10.0 ** (np.where(np.isfinite(js), js, 0.0) / 10.0), 0.0)
    return -10.0 * np.log10(10.0 ** (-np.asarray(cn0_nominal) / 10.0) + lin / JAM_Q_RC)


def gps_signal_quality(satellites: np.ndarray, js_db: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Satellites still tracked and the noise growth factor (>= 1) under jamming.

    The satellites in view have nominal C/N0 spread evenly from CN0_STRONG to CN0_WEAK; a satellite
    is tracked while its jammed C/N0 stays above CN0_TRACKING. Code-tracking noise grows as
    1/sqrt(C/N0), so position noise grows by 10^(loss/20) of the tracked satellites' mean loss.
    """
    sats = np.asarray(satellites, dtype=float)
    kmax = int(np.max(sats)) if sats.size else 0
    k = np.arange(kmax)
    frac = k[None, :] / np.maximum(sats[:, None] - 1.0, 1.0)
    nominal = CN0_STRONG - (CN0_STRONG - CN0_WEAK) * frac  # (N, kmax)
    in_view = k[None, :] < sats[:, None]
    eff = jammed_cn0(nominal, np.asarray(js_db, dtype=float)[:, None])
    tracked = in_view & (eff >= CN0_TRACKING)
    n_tracked = tracked.sum(axis=1).astype(float)
    loss = np.where(tracked, nominal - eff, 0.0).sum(axis=1) / np.maximum(n_tracked, 1.0)
    return n_tracked, 10.0 ** (loss / 20.0)
