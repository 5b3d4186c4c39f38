"""The vehicle as physics: rigid-body dynamics and motors, wind and disturbances, sensors, noise, rotations."""
