"""One mission flown in jMAVSim by the project's flight software, with or without SCART scenarios."""

from __future__ import annotations

import numpy as np

from scart_bench.dataset.schema import TOPICS
from scart_bench.generator.flight_software.navigator import mission_waypoints
from scart_bench.generator.hil.autopilot import HilAutopilot
from scart_bench.generator.hil.bridge import Bridge, HilFlight
from scart_bench.generator.hil.errors import HilError
from scart_bench.generator.hil.jmavsim import DEFAULT_SPEED, JMavSim
from scart_bench.generator.hil.link import SimLink
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


def mission_for(seed: int, mission: MissionParams | None = None) -> tuple[np.ndarray, float]:
    """The mission items (K, 3) and cruise speed of flight ``seed`` (the built-in engine's jitter)."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x5CA7]))
    rng.uniform(size=6)  # the built-in engine draws wind and heading first (engine.flight_batch)
    wps, cruise = mission_waypoints(mission or MissionParams(), [rng])
    return wps[0], float(cruise[0])


def autopilot_for(seed: int, scenarios: list[Scenario] | None = None, mission: MissionParams | None = None
                  ) -> HilAutopilot:
    """The flight software of flight ``seed``: its mission, and a layer when there are scenarios."""
    wps, cruise = mission_for(seed, mission)
    layer = AttackLayer([list(scenarios)], [int(seed)], rates=layer_rates()) if scenarios else None
    return HilAutopilot(wps, cruise, JMAVSIM, layer=layer, mission=mission)


def fly_jmavsim(jar=None, seed: int = 0, scenarios: list[Scenario] | None = None,
                mission: MissionParams | None = None, max_s: float | None = None, speed: float = DEFAULT_SPEED,
                first_timeout_s: float = 30.0) -> HilFlight:
    """Start jMAVSim (headless, lockstep, a free port), fly one mission through the bridge, stop it."""
    mp = mission or MissionParams()
    ap = autopilot_for(seed, scenarios, mp)
    with JMavSim(jar, speed=speed) as sim:
        link = SimLink(sim.address)
        try:
            return Bridge(link, ap).fly(max_s=max_s or mp.max_duration_s, first_timeout_s=first_timeout_s,
                                        alive=sim.alive)
        except HilError as exc:
            raise HilError(f"{exc} (jMAVSim said: {sim.last_line()})") from None
        finally:
            link.close()
