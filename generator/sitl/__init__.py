"""``scart-bench sitl``: the generator's vehicle as a PX4-like flight controller any MAVLink tool can fly.

- :mod:`scart_bench.generator.sitl.plant`: one vehicle's physics, sensors, estimator and controller, stepped
  at 250 Hz (the classes of the generator, called step by step);
- :mod:`scart_bench.generator.sitl.commander`: flight modes, arming, take-off, land, return, hold, the
  mission executor and offboard control, with PX4's custom modes, rules and parameters;
- :mod:`scart_bench.generator.sitl.handlers`: what the flight controller answers to a client (commands,
  mode changes, parameters, offboard setpoints, time sync);
- :mod:`scart_bench.generator.sitl.server`: the MAVLink endpoint on UDP, with the SCART layer between the
  flight controller and the mission computer, pacing by the wall clock (or lockstep) and the
  recording in the dataset layout;
- :mod:`scart_bench.generator.sitl.missions`: the mission protocol (PX4's mission manager: upload with
  retries and timeout, download, clear, set current);
- :mod:`scart_bench.generator.sitl.checks` and :mod:`~scart_bench.generator.sitl.bounds`: what the flight
  controller refuses (missions, commands, setpoints) and the answer a client gets;
- :mod:`scart_bench.generator.sitl.endpoint`: the socket, bound before the slow start-up;
- :mod:`scart_bench.generator.sitl.record` and :mod:`~scart_bench.generator.sitl.journal`: the recorded
  flight, written as it flies.

``docs/sitl.md`` describes what a client sees.
"""
