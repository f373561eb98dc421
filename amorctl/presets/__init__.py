"""Built-in training presets (TOML files read by :func:`amorctl.config.load_preset`)."""
