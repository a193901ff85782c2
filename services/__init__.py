"""The racestack services: planner, simulator, VESC driver, telemetry, localization bridge."""
