"""One module per `hostd` subcommand, each with `run(args) -> int`."""
