"""The MAVROS topics the SCART node carries (:mod:`scart_bench.generator.telemetry.mavros`, where they live
below the attack layer that reads their quantities), under the ROS package's own name.
"""

from scart_bench.generator.telemetry.mavros import (  # noqa: F401 (re-exported: the ROS node's names)
    COMMAND,
    MAVROS_TOPICS,
    SETPOINT_POSITION,
    SETPOINT_VELOCITY,
    STATE,
    RosTopic,
    field_quantity,
    topic_fields,
)
