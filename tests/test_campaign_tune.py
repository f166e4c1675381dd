"""taco_mav.campaign.tune: the search space's errors name the file and the key; Optuna (seeded) improves a
deliberately mistuned profile on a recorded drive (KITTI sequence 04, the emulator matcher, a few trials)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from taco_mav.campaign.tune import load_space
from taco_mav.config import load_profile
from taco_mav.errors import ConfigError

REPO = Path(__file__).resolve().parents[1]


def _space(tmp_path: Path, doc: dict) -> Path:
    path = tmp_path / "space.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


@pytest.mark.parametrize("doc, message", [
    ({"profile": "kitti", "parameters": {"ukf.sigma_fwd": {"low": 1, "high": 2}}}, "parameters.ukf.sigma_fwd: "
     "ukf.sigma_fwd: 'sigma_fwd' is not a key of ukf"),
    ({"profile": "kitti", "parameters": {"ukf.sigma_fwd_k": {"low": -1.0, "high": 2}}}, "ukf.sigma_fwd_k: -1.0 is out "
     "of range"),
    ({"profile": "kitti", "parameters": {"ukf.sigma_fwd_k": {"low": 2, "high": 1}}}, "low 2 must be below high 1"),
    ({"profile": "kitti", "parameters": {"gate.enabled": {"low": 0, "high": 1}}}, "gate.enabled is not a number"),
    ({"profile": "kitti", "parameters": {"ukf.sigma_fwd_k": {"low": 1, "hi": 2}}}, "sigma_fwd_k.hi: unknown key"),
    ({"profile": "kitti", "parameters": {}}, "parameters: expected a mapping"),
    ({"profile": "kitti", "trails": 3, "parameters": {"gate.enabled": {"choices": [True]}}}, "trails: unknown key"),
    ({"profile": "kitti", "coverage": [0.9, 0.5], "parameters": {"gate.enabled": {"choices": [True]}}}, "coverage: "),
])
def test_space_errors_name_the_file_and_the_key(tmp_path: Path, doc: dict, message: str) -> None:
    path = _space(tmp_path, doc)
    with pytest.raises(ConfigError) as err:
        load_space(path)
    assert str(path) in str(err.value) and message in str(err.value)


def test_tune_improves_a_mistuned_profile_on_a_recorded_drive(tmp_path: Path, kitti_root: Path) -> None:
    """The kitti profile with its fix noise 27 times too large (fixes barely move the filter: ATE 0.63 m on
    sequence 04 against 0.27 m as shipped); six seeded trials over the two numerators find a profile whose ATE
    is at least 0.2 m lower, with every report's error within 2 reported sigma held (coverage band 0.865..1)."""
    pytest.importorskip("ray")
    pytest.importorskip("optuna")
    from taco_mav.campaign.executor import RayOptions
    from taco_mav.campaign.spec import parse_campaign
    from taco_mav.campaign.tune import tune

    doc = yaml.safe_load((REPO / "vehicle_profiles" / "kitti.yaml").read_text())
    doc.update(name="kitti_mistuned")
    doc["ukf"] = {**doc.get("ukf", {}), "fix_fwd_num": 40.0, "fix_lat_num": 80.0, "fix_fwd_max_m": 100.0,
                  "fix_lat_max_m": 100.0}
    mistuned = tmp_path / "kitti_mistuned.yaml"
    mistuned.write_text(yaml.safe_dump(doc))
    space = load_space(_space(tmp_path, {
        "profile": str(mistuned), "trials": 6, "seed": 0, "coverage": [0.865, 1.0],
        "parameters": {"ukf.fix_fwd_num": {"low": 0.5, "high": 40.0, "log": True},
                       "ukf.fix_lat_num": {"low": 1.0, "high": 80.0, "log": True}}}))
    campaign = parse_campaign({"runs": [{"kind": "eval", "with": {"sequence": "04", "seed": 0}}]}, "kitti04.yaml")
    res = tune(campaign, space, tmp_path / "tune", {"kitti_root": str(kitti_root)}, RayOptions(num_cpus=2))
    assert res.baseline.median_error_m > 0.5  # 0.63 m at the time of writing: fixes barely count
    assert len(res.trials) == 6 and res.best.feasible
    assert res.best.median_error_m < res.baseline.median_error_m - 0.2
    best = load_profile(res.profile_path)
    assert best.name == "kitti_mistuned_tuned"
    assert (best.ukf.fix_fwd_num, best.ukf.fix_lat_num) == (res.best.values["ukf.fix_fwd_num"],
                                                           res.best.values["ukf.fix_lat_num"])
    assert best.ukf.fix_fwd_max_m == 100.0  # what was not searched stays as the profile had it
    assert f"median error {res.best.median_error_m} m" in res.profile_path.read_text().splitlines()[1]
    assert (tmp_path / "tune" / "tune.json").is_file()
