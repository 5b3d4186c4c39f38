"""``scart-bench sitl``: the generator's vehicle as a PX4-like flight controller any MAVLink tool can fly.

- :mod:`scart_bench.generator.sitl.plant`: one vehicle's physics, sensors, estimator and controller, stepped
  at 250 Hz (the classes of the generator, called step by step);
- :mod:`scart_bench.generator.sitl.commander`: flight modes, arming, take-off, land, return, hold, the
  mission executor and offboard control, with PX4's custom modes, rules and parameters;
- :mod:`scart_bench.generator.sitl.server`: the MAVLink endpoint on UDP, with the SCART layer between the
  flight controller and the mission computer, pacing by the wall clock (or lockstep) and the
  recording in the dataset layout.

``docs/sitl.md`` describes what a client sees.
"""
