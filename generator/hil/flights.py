"""One mission flown in jMAVSim by the project's flight software, with or without SCART scenarios."""

from __future__ import annotations

import numpy as np

from scart_bench.dataset.schema import TOPICS
from scart_bench.generator.flight_software.navigator import mission_table
from scart_bench.generator.hil.autopilot import HilAutopilot
from scart_bench.generator.hil.bridge import Bridge, HilFlight
from scart_bench.generator.hil.errors import HilError
from scart_bench.generator.hil.jmavsim import DEFAULT_SPEED, JMavSim
from scart_bench.generator.hil.link import open_link
from scart_bench.generator.hil.profiles import JMAVSIM
from scart_bench.generator.params import MissionParams
from scart_bench.generator.scart.layer import AttackLayer
from scart_bench.generator.scart.scenario import Scenario
from scart_bench.generator.telemetry.schedule import SENSOR_TOPICS


def layer_rates() -> dict[str, float]:
    """Message rates the layer sizes its history by (telemetry and sensor topics)."""
    rates = {t: v.rate_hz for t, v in TOPICS.items()}
    rates.update({t: r for t, (r, _) in SENSOR_TOPICS.items()})
    return rates


def mission_for(seed: int, mission: MissionParams | None = None
                ) -> tuple[np.ndarray, float, np.ndarray, int]:
    """The mission of flight ``seed`` as the built-in engine draws it: items (K, 3) NED, cruise speed,
    the navigator's item table (K, 6: north, east, down, leg speed, hold s, braking) and the last item.

    The jittered square by default; ``mission.missions`` (mission files: flight ``seed`` flies file
    ``seed mod N``) or ``mission.families`` (the family its seed draws) as in
    :func:`~scart_bench.generator.flight_software.navigator.mission_table`."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x5CA7]))
    rng.uniform(size=6)  # the built-in engine draws wind and heading first (engine.flight_batch)
    wps, cruise, table, last = mission_table(mission or MissionParams(), [int(seed)], [rng])
    return wps[0], float(cruise[0]), table[0], int(last[0])


def autopilot_for(seed: int, scenarios: list[Scenario] | None = None, mission: MissionParams | None = None
                  ) -> HilAutopilot:
    """The flight software of flight ``seed``: its mission, and a layer when there are scenarios."""
    wps, cruise, table, last = mission_for(seed, mission)
    layer = AttackLayer([list(scenarios)], [int(seed)], rates=layer_rates()) if scenarios else None
    return HilAutopilot(wps, cruise, JMAVSIM, layer=layer, mission=mission, table=table, last=last)


#: with jMAVSim in real time: how far (s) the flight software may fall behind the simulator's clock
#: before the flight is given up with a HilError; measured on a loaded 2-core machine, a flight that
#: fell 67-99 ms behind lost its attitude and crashed
REALTIME_MAX_LAG_S = 0.05


def fly_jmavsim(jar=None, seed: int = 0, scenarios: list[Scenario] | None = None,
                mission: MissionParams | None = None, max_s: float | None = None, speed: float = DEFAULT_SPEED,
                first_timeout_s: float = 30.0, transport: str = "udp", lockstep: bool = True) -> HilFlight:
    """Start jMAVSim (headless, a free port; lockstep unless ``lockstep`` is False, when it flies in
    real time), fly one mission through the bridge over ``transport`` (udp or tcp), stop it."""
    mp = mission or MissionParams()
    ap = autopilot_for(seed, scenarios, mp)
    with JMavSim(jar, speed=speed, transport=transport, lockstep=lockstep) as sim:
        try:
            return fly_at(sim.link_address, ap, max_s=max_s or mp.max_duration_s, first_timeout_s=first_timeout_s,
                          alive=sim.alive, max_lag_s=None if lockstep else REALTIME_MAX_LAG_S)
        except HilError as exc:
            raise HilError(f"{exc} (jMAVSim said: {sim.last_line()})") from None


def fly_at(address: str, autopilot: HilAutopilot, max_s: float = 150.0, first_timeout_s: float = 30.0,
           alive=None, max_lag_s: float | None = None) -> HilFlight:
    """Fly ``autopilot`` against a simulator that is already running at ``address`` (``udp:HOST:PORT``,
    ``tcp:HOST:PORT``, ``udp-listen:HOST:PORT`` or ``tcp-listen:HOST:PORT``: see
    :func:`scart_bench.generator.hil.link.open_link`); the simulator's clock sets the pace. With a
    simulator in real time, ``max_lag_s`` bounds how far the flight software may fall behind it."""
    link = open_link(address)
    try:
        return Bridge(link, autopilot, max_lag_s=max_lag_s).fly(max_s=max_s, first_timeout_s=first_timeout_s,
                                                                alive=alive)
    finally:
        link.close()
