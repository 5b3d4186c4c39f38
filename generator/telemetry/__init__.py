"""The flight controller's telemetry: message schedules and composition (:mod:`.schedule`), realistic
timing (:mod:`.timing`), the uORB view (:mod:`.uorb`) and the per-flight tables of a flown batch (:mod:`.tables`)."""
