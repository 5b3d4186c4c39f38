"""``generate --like``: measure the logs, write the fitted profile TOML and the recovered missions.

The folder gets ``profile.toml`` and ``missions/<log>.waypoints`` (one recovered mission per log that
flew), referenced from the TOML relative to it, so the folder can be moved and the TOML edited and
given to ``generate --profile FILE.toml``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

from scart_bench.generator.like import fit as fitting
from scart_bench.generator.like import tracks
from scart_bench.generator.like.profile_file import render

PROFILE_NAME = "profile.toml"
MISSION_DIR = "missions"

#: what the logs show that the generator cannot take yet (key -> why), listed in the TOML and docs/like.md
NOT_EXPRESSIBLE = {
    "ground_before_takeoff_s": "the ground phase before arming is the PX4 start-up model's (generator.flight_software."
                               "startup: 3.8-16 s from boot); measured in [measured] ground_before_s",
    "ground_noise": "the IMU noise on the ground (motors armed or not) follows the flight's noise model; measured "
                    "per axis in [measured] ground_*",
    "message_rates": "rates are the dataset schema's, one per topic for every flight (highres_imu and attitude "
                     "50 Hz, ...); measured per quantity in [measured] rate_*. The jitter, drops and late messages "
                     "are fitted per topic ([timing]) as a CV, so a topic at another rate keeps the log's CV",
    "baro_timing": "the generated baro altitude rides on highres_imu (HIGHRES_IMU.pressure_alt) at the IMU's "
                   "timing; the baro's own figures go to scaled_pressure in [timing]",
    "site": "home latitude/longitude/altitude are the dataset schema's (PX4 SITL, Zurich); the recovered missions "
            "keep their log's home in their WPL files and are flown as offsets from the generator's home",
    "mag_per_axis": "one magnetometer noise for x, y and z; fitted to the mean of the three axes",
    "gusts": "gust_sigma_max and gust_tau are not measured (the estimator's wind states are smooth); defaults kept",
    "airframe": "the vehicle (mass, inertia, motors, drag) stays the base profile's: thrust and attitude logs do "
                "not pin it down without the airframe's parameters",
}


def fit_to_folder(paths: list[str], folder: str | Path, base: str = "quick", say: Callable[[str], None] = print,
                  calibrate: bool = True) -> Path:
    """Measure ``paths``, write ``folder``/profile.toml and its missions; returns the TOML's path.

    Every log is read first (a log that cannot be read raises, naming it); what a log cannot give is
    said in one line and the default kept."""
    from scart_bench.generator.profiles import PROFILES

    folder = Path(folder)
    logs = []
    for p in paths:
        m = fitting.measure_log(p)
        logs.append(m)
    for m in logs:
        say(fitting.log_line(m))
        for note in m.notes:
            say(f"  {m.name}: {note}")
    config = PROFILES[base].flight_config()
    fitted = fitting.fit_fleet(logs, config, calibrate=calibrate)
    for line in fitted.lines:
        say(f"fleet: {line}")
    folder.mkdir(parents=True, exist_ok=True)
    (folder / MISSION_DIR).mkdir(exist_ok=True)
    missions = []
    levels = []  # each written mission's vehicle vibration (SensorParams.vibration_levels), in the missions' order
    rocking = []  # ... and its rocking (MissionParams.rocking_levels)
    flow = []  # ... and its rocking in forward flight (MissionParams.rocking_flow_levels)
    names = set()
    for m in logs:
        name = _unique(Path(m.name).stem, names)
        target = folder / MISSION_DIR / f"{name}.waypoints"
        written = _write_mission(m, target, config.mission.cruise_speed)
        if written:
            missions.append(f"{MISSION_DIR}/{target.name}")
            levels.append(list(fitted.vibration_levels.get(m.name, (1.0,) * 6)))
            rocking.append(list(fitted.rocking_levels.get(m.name, (0.0,) * 3)))
            flow.append(list(fitted.flow_levels.get(m.name, (0.0,) * 2)))
        elif m.mission_source:
            say(f"  {m.name}: its mission could not be written ({written is None and 'no waypoints' or 'refused'})")
    sections = {"profile": {"base": (base, "flight counts, splits and attack grid of this built-in profile")}}
    sections["profile"]["timing"] = ("realistic", "jitter, drops and late messages: the realistic table with the "
                                                  "[timing] entries fitted to the logs")
    airframes = getattr(PROFILES[base], "airframes", None)
    if airframes:
        sections["profile"]["airframes"] = (dict(airframes), f"the {base} profile's airframe mix: not fitted (a log "
                                                             "does not name its airframe); edit to your frame")
    sections["profile"].update(_gps_level(logs))
    sections["sensors"] = fitted.values["sensors"]
    sections["estimator"] = fitted.values["estimator"]
    sections["mission"] = dict(fitted.values["mission"])
    if missions and fitted.vibration_levels and any(v != [1.0] * 6 for v in levels):
        sections["sensors"]["vibration_levels"] = (levels, "each mission's vehicle: accelerometer x/y/z, gyro x/y/z "
                                                   "sample-to-sample noise in the air over the fleet's (its still "
                                                   "hover, or every airborne row), in the missions' order: "
                                                   + "; ".join(f"{Path(p).stem} " + "/".join(f"{x:g}" for x in v)
                                                               for p, v in zip(missions, levels)))
    if missions and fitted.rocking_levels and any(any(v) for v in rocking):
        sections["mission"]["rocking_levels"] = (rocking, "each mission's vehicle: white angular acceleration (rad/s^2 per "
                                                "step, roll/pitch/yaw) that gives its log's gyro sample-to-sample noise "
                                                "in the air, in the missions' order: "
                                                + "; ".join(f"{Path(p).stem} " + "/".join(f"{x:g}" for x in v)
                                                            for p, v in zip(missions, rocking)))
    if missions and fitted.flow_levels and any(any(v) for v in flow):
        sections["mission"]["rocking_flow_levels"] = (flow, "each mission's vehicle: angular acceleration in forward "
                                                      "flight (rad/s^2 at full speed, roll/pitch) that gives its log's "
                                                      "roll/pitch power in 1-5 Hz moving faster than 1 m/s (a log "
                                                      "without: the median), in the missions' order: "
                                                      + "; ".join(f"{Path(p).stem} " + "/".join(f"{x:g}" for x in v)
                                                                  for p, v in zip(missions, flow)))
    else:
        for key in ("rocking_flow_hz", "rocking_flow_from_m_s", "rocking_flow_full_m_s"):
            sections["mission"].pop(key, None)
    if missions:
        sections["mission"]["missions"] = (missions, f"recovered from {len(missions)} of {len(logs)} logs; the flight "
                                                     "with seed s flies file s mod N")
    else:
        say("fleet: no log gave a mission: the flights fly the base profile's square")
    if fitted.values.get("timing"):
        sections["timing"] = fitted.values["timing"]
    else:
        say("fleet: no log has 50 messages of a timed topic: the realistic timing table kept")
    sections["measured"] = {k: (round(v, 4) if math.isfinite(v) else v, c) for k, (v, c) in fitted.measured.items()}
    sections["not_expressible"] = {k: (v, "") for k, v in NOT_EXPRESSIBLE.items()}
    sections["logs"] = {f'"{m.name}"': (fitting.log_line(m).split(": ", 1)[1], "") for m in logs}
    header = [f"scart-bench flight profile fitted by `scart-bench generate --like` to {len(logs)} log(s):",
              *(f"  {p}" for p in paths),
              "Each value's comment says where it came from (which figure, which segment, median over how many logs).",
              "`scart-bench generate --profile THIS_FILE --out DIR` flies it; edit it freely (a bad value is refused",
              "naming its key). [measured], [not_expressible] and [logs] are for the reader and are not applied.", ""]
    path = folder / PROFILE_NAME
    path.write_text(render(header, sections), encoding="utf-8")
    return path


def _gps_level(logs) -> dict:
    eph = [m.eph for m in logs if math.isfinite(m.eph)]
    if not eph:
        return {}
    import numpy as np

    med = float(np.median(eph))
    level = "real_receiver" if med > 1.0 else "simulator"
    return {"gps_accuracy": (level, f"median eph {med:.2f} m over {len(eph)} logs; the [sensors] gps_* fields refine it")}


def _unique(stem: str, names: set) -> str:
    name, k = stem, 2
    while name in names:
        name, k = f"{stem}_{k}", k + 1
    names.add(name)
    return name


def _write_mission(m: fitting.LogMeasure, target: Path, cruise: float) -> bool | None:
    """Write the log's mission to ``target`` and read it back; False when the reader refuses it."""
    from scart_bench.dataset.schema import HOME_ALT, HOME_LAT, HOME_LON
    from scart_bench.generator.flight_software.mission_files import MissionFileError, read_wpl

    home = m.home or (HOME_LAT, HOME_LON, HOME_ALT)
    if not all(math.isfinite(v) for v in home):
        home = (home[0], home[1], HOME_ALT)
    if m.mission_rows:
        lines = ["QGC WPL 110", tracks._wpl(0, 0, 0, 16, [0, 0, 0, 0, *home])]
        lines += [tracks._wpl(i + 1, frame, 0, cmd, p) for i, (cmd, frame, p) in enumerate(m.mission_rows)]
        target.write_text("\n".join(lines) + "\n", encoding="utf-8")
    elif m.mission:
        tracks.write_wpl(target, m.mission, home, cruise)
    else:
        return None
    try:
        read_wpl(target)
    except MissionFileError as e:
        target.unlink()
        m.notes.append(f"recovered mission refused ({e}): not flown")
        return False
    return True
