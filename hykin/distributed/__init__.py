"""Sweeps and fleets on Ray (issue #29): a layer above evaluation/measure/hybrid, below cli.

Modules:

* ``files`` — TOML reading, relative paths, one-line :class:`~hykin.distributed.files.SpecError`.
* ``options`` — the one up-front check of fit options (sweep [grid] / [random], fleet [robot.fit]) and data units.
* ``sweep_file`` — SWEEP.toml -> :class:`~hykin.distributed.sweep_file.SweepSpec` and its trials.
* ``fleet_file`` — FLEET.toml -> :class:`~hykin.distributed.fleet_file.FleetSpec`.
* ``trials`` — the one trial: `hykin fit` options -> fitted model -> test errors.
* ``ray_session`` — Ray imported lazily (extra ``distributed``), a local or cluster session.
* ``trial_pool`` — the trials on long-lived Ray actors (one per trial slot), each retried once.
* ``sweep`` — the sweep driver: results.csv, the error-vs-size plot, resume.
* ``fleet`` — the Ray core driver: per-robot models, summary.csv and summary.md.
"""
