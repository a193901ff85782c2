"""A Zenoh router on the well-known hub endpoint that every other service connects to."""
