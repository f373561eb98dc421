"""Built-in training presets (TOML files read by :func:`amorctl.core.config.load_preset`)."""
