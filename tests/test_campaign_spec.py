"""taco_mav.campaign.spec: campaign files -> runs (grid expansion, defaults, ids), and the errors that name the
file and the key; taco_mav.campaign.overrides: dotted profile keys."""

from __future__ import annotations

from pathlib import Path

import pytest

from taco_mav.campaign.overrides import apply_overrides, key_type
from taco_mav.campaign.spec import load_campaign, parse_campaign
from taco_mav.config import load_profile
from taco_mav.errors import ConfigError

REPO = Path(__file__).resolve().parents[1]


def test_a_grid_is_every_combination_with_the_fixed_parameters() -> None:
    doc = {"name": "g", "seed": 4, "runs": [
        {"kind": "sim", "grid": {"estimator": ["taco+", "paper"], "seed": [1, 2, 3]}, "with": {"duration_s": 20}},
        {"kind": "eval", "with": {"sequence": "04"}}]}
    c = parse_campaign(doc, "g.yaml")
    assert c.name == "g" and len(c.runs) == 7
    sims = [r for r in c.runs if r.kind == "sim"]
    assert [(r.params["estimator"], r.params["seed"]) for r in sims] == [
        ("taco+", 1), ("taco+", 2), ("taco+", 3), ("paper", 1), ("paper", 2), ("paper", 3)]
    assert all(r.params["duration_s"] == 20 and r.params["length_km"] == 0.3 for r in sims)  # a default filled in
    assert sims[0].factors == {"duration_s": 20, "estimator": "taco+", "seed": 1}
    assert sims[0].configuration() == "sim: duration_s=20, estimator=taco+"
    assert sims[0].configuration() == sims[2].configuration() != sims[3].configuration()
    ev = c.runs[-1]
    assert ev.params["seed"] == 4 and ev.params["profile"] == "kitti"  # the campaign's seed where a run names none
    assert len({r.run_id for r in c.runs}) == 7
    # ids are stable: the same file, the same ids; a changed parameter, another id
    assert [r.run_id for r in parse_campaign(doc, "g.yaml").runs] == [r.run_id for r in c.runs]
    doc["runs"][0]["with"]["duration_s"] = 21
    assert parse_campaign(doc, "g.yaml").runs[0].run_id != c.runs[0].run_id
    assert sims[0].run_id.startswith("sim-estimator=taco+-seed=1-")


def test_resources_default_to_the_kinds_and_take_overrides() -> None:
    c = parse_campaign({"runs": [{"kind": "eval", "with": {"sequence": "04"}, "resources": {"num_cpus": 0.5, "gpu_x": 1}},
                                 {"kind": "sim"}]}, "r.yaml")
    assert (c.runs[0].num_cpus, c.runs[0].resources) == (0.5, {"gpu_x": 1.0})
    assert (c.runs[1].num_cpus, c.runs[1].resources) == (1.0, {})


@pytest.mark.parametrize("doc, message", [
    ({"runs": [{"kind": "sim", "grid": {"lenght_km": [1]}}]}, "c.yaml: runs[0].grid.lenght_km: unknown parameter of a sim run"),
    ({"runs": [{"kind": "sim", "with": {"speed": "fast"}}]}, "c.yaml: runs[0].with.speed: expected a number, got 'fast'"),
    ({"runs": [{"kind": "sim", "grid": {"estimator": ["taco+", "tacoo"]}}]}, "c.yaml: runs[0].grid.estimator: 'tacoo' is not one of"),
    ({"runs": [{"kind": "sim", "grid": {"seed": 3}}]}, "c.yaml: runs[0].grid.seed: expected a non-empty list"),
    ({"runs": [{"kind": "drive"}]}, "c.yaml: runs[0].kind: 'drive' is not one of ardupilot, px4, sim, eval"),
    ({"runs": [{"kind": "sim", "gird": {}}]}, "c.yaml: runs[0].gird: unknown key (known: kind, grid, with, resources)"),
    ({"runs": [{"kind": "sim", "with": {"set": {"ukf.sigma_fwd": 1.0}}}]}, "'sigma_fwd' is not a key of ukf"),
    ({"runs": [{"kind": "sim"}, {"kind": "sim"}]}, "c.yaml: runs[1]: a run with the same parameters as one of runs[0]"),
    ({"runs": [{"kind": "sim", "grid": {"seed": [1]}, "with": {"seed": 2}}]}, "runs[0].grid.seed: also under with"),
    ({"runs": [{"kind": "sim", "resources": {"num_cpus": -1}}]}, "runs[0].resources.num_cpus: expected an amount >= 0"),
    ({"runs": []}, "c.yaml: runs: expected a non-empty list"),
    ({"runs": [{"kind": "sim"}], "seeds": [1]}, "c.yaml: seeds: unknown key"),
])
def test_errors_name_the_file_and_the_key(doc: dict, message: str) -> None:
    with pytest.raises(ConfigError) as err:
        parse_campaign(doc, "c.yaml")
    assert message in str(err.value)


def test_a_file_that_is_not_yaml_is_named(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("runs: [kind: sim\n")
    with pytest.raises(ConfigError, match=f"{bad}: not valid YAML"):
        load_campaign(bad)


def test_the_shipped_campaigns_are_valid() -> None:
    """tools/campaigns/*.yaml: the smoke campaign CI runs is small; the claims campaign has both autopilots, solo
    and hand-over, flat and 3-D worlds, the fault runs, five seeds each."""
    smoke = load_campaign(REPO / "tools/campaigns/smoke.yaml")
    assert {r.kind for r in smoke.runs} == {"sim"} and len(smoke.runs) <= 6
    claims = load_campaign(REPO / "tools/campaigns/claims.yaml")
    kinds = {r.kind for r in claims.runs}
    assert {"ardupilot", "px4"} <= kinds
    for kind in ("ardupilot", "px4"):
        runs = [r for r in claims.runs if r.kind == kind]
        assert {r.params["setup"] for r in runs} >= {"solo", "handover"}
        assert {r.params["realism"] for r in runs} == {"flat", "3d"}
    assert {r.params["fault"] for r in claims.runs if r.kind == "ardupilot"} > {None}
    per_config: dict[str, set[int]] = {}
    for r in claims.runs:
        per_config.setdefault(r.configuration(), set()).add(r.params["seed"])
    assert all(len(seeds) == 5 for seeds in per_config.values())


def test_profile_keys_are_checked_against_the_profile() -> None:
    assert key_type("ukf.sigma_fwd_k", "s") is float and key_type("gate.enabled", "s") is bool
    with pytest.raises(ConfigError, match=r"s: ukf: a section, not a value"):
        key_type("ukf", "s")
    with pytest.raises(ConfigError, match=r"s: name.x: name is a value, not a section"):
        key_type("name.x", "s")
    with pytest.raises(ConfigError, match=r"'nope' is not a key of the profile"):
        key_type("nope.x", "s")
    kitti = load_profile("kitti")
    assert apply_overrides(kitti, {"ukf.sigma_fwd_k": 1}, "s").ukf.sigma_fwd_k == 1.0
    with pytest.raises(ConfigError, match=r"ukf.sigma_fwd_k: -1.0 is out of range"):
        apply_overrides(kitti, {"ukf.sigma_fwd_k": -1.0}, "s")
