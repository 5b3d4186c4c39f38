"""scart-bench's flight generator and the SCART attack layer, grouped by subsystem.

- :mod:`.physics`: the vehicle's rigid-body dynamics, wind and disturbances, sensors and their noise;
- :mod:`.flight_software`: what runs on the flight controller (estimator and cascade, commander with
  PX4's failsafes, the PX4 start on the ground) and the mission computer's navigator;
- :mod:`.engine`: the closed loop, numpy reference step (:mod:`.engine.simulate`) and compiled
  kernel (:mod:`.engine.kernel`, driven by :mod:`.engine.compiled`) side by side;
- :mod:`.telemetry`: the link's message schedules, realistic timing, the uORB view and the tables a
  flown batch becomes;
- :mod:`.scart`: the attack layer (scenarios, conditions, actions, grids);
- :mod:`.logs`: your own logs (import, csv-mode attacks on them);
- :mod:`.mavlink` and :mod:`.sitl`: the live link (proxy) and the simulated vehicle any MAVLink tool flies.

At the top: :mod:`.generate` (datasets), :mod:`.profiles`, :mod:`.attacks` (attacked flights in both
modes), :mod:`.modes`, :mod:`.attack_effect`, :mod:`.impact`, :mod:`.geo` and :mod:`.params`.
"""

__version__ = "0.1.0"
