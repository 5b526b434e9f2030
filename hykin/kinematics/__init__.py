"""hykin.kinematics."""
