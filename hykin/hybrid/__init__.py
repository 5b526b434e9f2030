"""hykin.hybrid."""
