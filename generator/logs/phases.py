"""Mission phases of a recorded flight (:mod:`scart_bench.generator.telemetry.phases`, where they live below
the attack layer's phase conditions), under the log package's own name.
"""

from scart_bench.generator.telemetry.phases import (  # noqa: F401 (re-exported: the names logs, tests and docs use)
    ALTITUDE_SOURCES,
    ANCHORS,
    CLIMB,
    LANDED,
    PHASE_TOPIC,
    PHASES,
    TAKEOFF,
    TAKEOFF_HEIGHT_M,
    altitude_source,
    flight_phases,
    mission_progress,
    phase_at,
    phase_progress,
    phase_topic,
)
