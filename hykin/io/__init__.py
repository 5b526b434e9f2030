"""hykin.io."""
