"""Robot presets shipped with hykin (TOML robot files, DESIGN.md §3)."""
