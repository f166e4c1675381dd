"""The `taco-mav` subcommands, one function each (`cmd_<name>(args) -> exit code`), grouped by what they
touch: `offline` (files: bench, world, eval, drift, calibrate), `live` (MAVLink: run, sim, demo) and `mission` (a
closed-loop mission on ArduPilot or PX4 SITL). The parser, the global flags and the error contract are
`taco_mav.cli` and `taco_mav.cli_support`."""
