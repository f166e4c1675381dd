"""The `taco-mav` subcommands, one function each (`cmd_<name>(args) -> exit code`), grouped by what they
touch: `offline` (files: bench, world, eval, drift, calibrate) and `live` (MAVLink: run, sim, demo). The parser,
the global flags and the error contract are `taco_mav.cli` and `taco_mav.cli_support`."""
