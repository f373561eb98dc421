"""Built-in plugins, registered through the ``amorctl`` entry-point group like third-party ones."""
