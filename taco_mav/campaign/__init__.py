"""Validation campaigns: many runs of the kinds taco_mav already has (ArduPilot and PX4 SITL missions, the
in-process simulator, offline evaluations of KITTI or recorded drives), spread over Ray, written one result per
run, summarised per configuration, and a profile tuned against them (docs/campaign.md).

One idea a module:

- `spec`: the campaign file (YAML) -> the runs it names (a grid or a list), validated, each with a stable id;
- `kinds`: the run kinds: the parameters each takes, its resources, the figures it is scored by;
- `overrides`: dotted profile keys (`ukf.sigma_fwd_k`) checked against the profile and applied;
- `execute`: one run of each kind, in the process that `child` starts;
- `child`: the process a run lives in (its own network namespace and /tmp for SITL missions) and the Ray task
  that starts it;
- `executor`: Ray: resources per run, retries of lost workers, results written as runs finish, resume;
- `results`: the per-run JSON files -> one table (Parquet, else CSV);
- `summary`: p50 / p95 / worst error, coverage, completion and failsafe counts per configuration;
- `plot`: a box per configuration;
- `tune`: Optuna over a profile's parameters against a campaign's objective.

Ray, Optuna and pyarrow come with the `campaign` extra (`pip install -e '.[campaign]'`); nothing here imports
them at module level.
"""
