"""The command-line interface: one thin module per subcommand; the only place that prints."""
