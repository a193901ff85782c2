"""What every racestack service needs: configuration, track geometry, curvature, messages."""
