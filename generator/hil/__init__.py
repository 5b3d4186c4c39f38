"""External simulators in the loop: the project's flight software speaking PX4's simulator MAVLink API.

- :mod:`~scart_bench.generator.hil.autopilot`: the flight software fed one sensor sample at a time,
  with the SCART layer at the sensor and link points;
- :mod:`~scart_bench.generator.hil.link`: the MAVLink messages (HIL_SENSOR, HIL_GPS,
  HIL_STATE_QUATERNION in; HIL_ACTUATOR_CONTROLS, HEARTBEAT out) over UDP;
- :mod:`~scart_bench.generator.hil.bridge`: the lockstep loop between the two;
- :mod:`~scart_bench.generator.hil.jmavsim`: starting and stopping jMAVSim;
- :mod:`~scart_bench.generator.hil.profiles`: the simulator's airframe as the controller sees it.
"""
