"""Test configuration: property tests are reproducible (fixed example sequence, no example database),
so a CI run fails or passes the same way every time."""

from hypothesis import settings

settings.register_profile("hykin", derandomize=True, database=None, deadline=None)
settings.load_profile("hykin")
