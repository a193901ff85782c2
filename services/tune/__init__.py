"""``racestack tune``: parameter search of a method for the fastest clean laps (Optuna)."""
