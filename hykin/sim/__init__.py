"""Virtual robots whose truth is known, and sampling plans (DESIGN.md §1.4).

:mod:`.simulate` (:class:`VirtualRobot`, its errors, true poses, simulated measurements, truth files),
:mod:`.presets` (named virtual robots: ``rx160-virtual`` ...; ``python -m hykin.sim.presets`` measures
their dataset errors), :mod:`.generate` (``hykin simulate``: data file + truth file), :mod:`.sampling`
(uniform, random, zig-zag, ISO 9283 cube, restricted), and the generated battery (docs/battery.md):
:mod:`.random_robots` (random DH / MDH / URDF robots, their files and true robots), :mod:`.random_campaigns`
(random measurement campaigns and user mistakes, as files), :mod:`.battery` (run one through the CLI and
judge it). Depends on :mod:`hykin.io`,
:mod:`hykin.kinematics`, :mod:`hykin.geometry`.
"""
