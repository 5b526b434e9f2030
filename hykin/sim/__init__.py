"""hykin.sim."""
