"""hykin.measure."""
