"""Flight software: the flight controller (estimator, cascade, land detector, commander with PX4's failsafes,
the PX4 start on the ground) and the mission computer's navigator."""
