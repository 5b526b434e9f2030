"""hykin.evaluation."""
