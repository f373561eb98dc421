"""Built-in objective sets (each module is one plugin named by an entry point)."""
