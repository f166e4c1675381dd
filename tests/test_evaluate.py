import json
import math

import numpy as np
import pytest

from taco_mav.errors import ConfigError, DataError, MatcherError
from taco_mav.evaluation.evaluate import EvalRequest, evaluate

CONTRACT = ("ate_m", "ate_imu_only_m", "ate_smoothed_m", "length_km", "ate_m_per_km", "steady_rmse_m",
            "fixes_per_km", "attempts", "accepted", "camera_duty_cycle")


def _req(tmp_path, kitti_root, **kw):
    base = dict(out=tmp_path / "run", kitti_root=kitti_root, sequences=("04",), plots=False, progress=False)
    base.update(kw)
    return EvalRequest(**base)


def test_eval_writes_the_contract_and_is_deterministic(tmp_path, kitti_root):
    r1 = evaluate(_req(tmp_path, kitti_root, plots=True))
    r2 = evaluate(_req(tmp_path, kitti_root, out=tmp_path / "again"))
    s = r1["sequences"]["04"]
    for key in CONTRACT:
        assert key in s
    timing = ("wall_s", "matcher_s_per_100m")
    strip = lambda r: {k: {f: v for f, v in m.items() if f not in timing} for k, m in r["sequences"].items()}  # noqa: E731
    assert strip(r1) == strip(r2)  # identical numbers on re-run (wall-clock timings aside)
    assert 0.35 < s["length_km"] < 0.45 and s["accepted"] >= 5
    assert s["ate_m"] < s["ate_imu_only_m"] or s["ate_m"] < 1.0
    assert 0.0 < s["camera_duty_cycle"] < 0.2
    written = json.loads((tmp_path / "run" / "results.json").read_text())
    assert written["summary"]["median_ate_m"] == s["ate_m"]
    table = (tmp_path / "run" / "table.md").read_text().splitlines()
    assert table[0] == "TACO, estimator paper, matcher emulator" and table[2].startswith("| System | 04 |")
    for name in ("trajectory.png", "error_vs_distance.png", "error_cdf.png", "online.tum", "online.kitti"):
        assert (tmp_path / "run" / "04" / name).stat().st_size > 0
    assert (tmp_path / "run" / "config.yaml").read_text().count("yaw_residual_max_rad: 0.35") == 1


def test_ate_agrees_with_an_independent_computation_on_the_exported_files(tmp_path, kitti_root):
    res = evaluate(_req(tmp_path, kitti_root))
    est = np.loadtxt(tmp_path / "run" / "04" / "online.tum")
    gt = np.loadtxt(tmp_path / "run" / "04" / "truth.tum")
    assert np.array_equal(est[:, 0], gt[:, 0])
    # rigid first-pose alignment done by hand: rotate about the first pose by the heading difference
    yaw = lambda row: 2 * math.atan2(row[6], row[7])  # noqa: E731
    d = yaw(gt[0]) - yaw(est[0])
    R = np.array([[math.cos(d), -math.sin(d)], [math.sin(d), math.cos(d)]])
    aligned = (est[:, 1:3] - est[0, 1:3]) @ R.T + gt[0, 1:3]
    ate = math.sqrt(np.mean(np.sum((aligned - gt[:, 1:3]) ** 2, axis=1)))
    assert ate == pytest.approx(res["sequences"]["04"]["ate_m"], abs=2e-4)
    # the same error split along and across the true heading (KITTI's pose files carry it)
    th = np.array([yaw(row) for row in gt])
    d_xy = aligned - gt[:, 1:3]
    along = d_xy[:, 0] * np.cos(th) + d_xy[:, 1] * np.sin(th)
    cross = -d_xy[:, 0] * np.sin(th) + d_xy[:, 1] * np.cos(th)
    s = res["sequences"]["04"]
    assert math.sqrt(np.mean(along**2)) == pytest.approx(s["ate_along_m"], abs=2e-4)
    assert math.sqrt(np.mean(cross**2)) == pytest.approx(s["ate_cross_m"], abs=2e-4)


def test_latency_compensation_beats_naive_application(tmp_path, kitti_root):
    base = evaluate(_req(tmp_path, kitti_root, sequences=("07",)))["sequences"]["07"]["ate_m"]
    comp = evaluate(_req(tmp_path, kitti_root, sequences=("07",), latency_s=1.0, out=tmp_path / "c"))["sequences"]["07"]["ate_m"]
    naive = evaluate(_req(tmp_path, kitti_root, sequences=("07",), latency_s=1.0, apply_on_arrival=True,
                          out=tmp_path / "n"))["sequences"]["07"]["ate_m"]
    assert comp < base + 1.0
    assert naive > comp + 2.0


def test_every_ablation_switch_changes_behaviour(tmp_path, kitti_root):
    profile = tmp_path / "locks.yaml"
    profile.write_text("name: locks\nmatcher: emulator\nimu:\n  gyro_arw: 5.8e-5\nemulator:\n  symmetric_lock_rate: 0.3\n")
    res = evaluate(_req(tmp_path, kitti_root, sequences=("07",), profile=profile, ablations=("all",)))
    ab = res["ablations"]
    full = ab["full"]["sequences"]["07"]
    assert ab["no_yaw_gate"]["accepted"] > ab["full"]["accepted"]  # locks get in without the gate
    assert full["rejected"].get("yaw_gate", 0) > 0 and "yaw_gate" not in ab["no_yaw_gate"]["sequences"]["07"]["rejected"]
    for name in ("single_crop", "isotropic_noise"):
        assert ab[name]["sequences"]["07"]["ate_m"] != full["ate_m"], name
    # the emulator's answer does not depend on where inside its capture radius a crop is, so the forward bias
    # shows in the search geometry. Our UKF is predicted to the capture time, so the paper's bias (meant for
    # a filter that lags at the last anchor) puts the centre 0.4 eps ahead of the vehicle: farther, not nearer.
    nb = ab["no_forward_bias"]["sequences"]["07"]
    assert full["search_centre_error_median_m"] > nb["search_centre_error_median_m"] + 0.1
    assert ab["ukf_only"]["sequences"]["07"]["ate_smoothed_m"] is None and full["ate_smoothed_m"] is not None
    assert "- single crop" in (tmp_path / "run" / "table.md").read_text()


def test_clear_errors(tmp_path, kitti_root):
    with pytest.raises(DataError, match="unknown sequence '42'"):
        evaluate(_req(tmp_path, kitti_root, sequences=("42",)))
    with pytest.raises(DataError, match="2011_10_03_drive_0027"):
        evaluate(_req(tmp_path, kitti_root, sequences=("00",)))  # not in the shared data
    with pytest.raises(MatcherError, match="needs camera images"):
        evaluate(_req(tmp_path, kitti_root, matcher="classical"))
    with pytest.raises(ConfigError, match="--kitti-root"):
        evaluate(_req(tmp_path, None))
    with pytest.raises(ConfigError, match="unknown nope"):
        evaluate(_req(tmp_path, kitti_root, ablations=("nope",)))


def test_synthetic_world_with_the_classical_matcher_end_to_end(tmp_path):
    from taco_mav.datasets.synthetic import build_world

    world = build_world(tmp_path / "world", seed=3, length_km=0.3, progress=False)
    res = evaluate(EvalRequest(out=tmp_path / "run", drives=(world,), profile="synthetic", matcher="classical",
                               plots=False, progress=False))
    (s,) = res["sequences"].values()
    assert s["accepted"] >= 10 and s["accepted"] >= 0.8 * s["attempts"]
    assert s["ate_m"] < 2.0 < s["ate_imu_only_m"] or s["ate_m"] < 0.5 * s["ate_imu_only_m"]
    assert s["matcher_s_per_100m"] is not None and s["matcher_s_per_100m"] > 0


def test_taco_plus_beats_paper_mode_on_real_kitti_at_a_fraction_of_the_fixes(tmp_path, kitti_root):
    """KITTI 05 and 07 OXTS (FG2 same-area emulator, seed 0, 1 s-late fixes): taco+ has a lower ATE
    than paper mode at under half its fixes and within the 40 fixes/km budget, never declares a loss of lock,
    and its offline smoother improves on its online estimate."""
    seqs = ("05", "07")
    paper = evaluate(_req(tmp_path, kitti_root, sequences=seqs, latency_s=1.0, estimator="paper"))["sequences"]
    plus = evaluate(_req(tmp_path, kitti_root, sequences=seqs, latency_s=1.0, estimator="taco+",
                         out=tmp_path / "plus"))["sequences"]
    for s in seqs:
        p, q = paper[s], plus[s]
        assert q["ate_m"] < 0.75 * p["ate_m"] and q["ate_m"] < 0.6
        assert q["fixes_per_km"] <= 40 and q["fixes_per_km"] < 0.5 * p["fixes_per_km"]
        assert q["camera_duty_cycle"] < 0.05
        assert q["lock_losses"] == 0 and q["honest_fraction"] >= 0.99
        assert q["ate_smoothed_m"] < q["ate_m"]


def test_cross_area_flag_uses_fg2s_cross_area_figures(tmp_path, kitti_root):
    same = evaluate(_req(tmp_path, kitti_root, estimator="taco+"))
    cross = evaluate(_req(tmp_path, kitti_root, estimator="taco+", cross_area=True, out=tmp_path / "x"))
    assert cross["config"]["emulator"]["cross_area_sequences"] == ["04"]
    assert cross["sequences"]["04"]["ate_m"] > 1.5 * same["sequences"]["04"]["ate_m"]  # 4.15 m vs 0.51 m fixes
    # the accepted fixes' own error against the truth, along and across the track: 4.15 m vs 0.51 m answers
    # before the consensus; the emulator puts twice the spread across the track as along it
    for key in ("fix_error_along_rms_m", "fix_error_cross_rms_m"):
        assert cross["sequences"]["04"][key] > 2.0 * same["sequences"]["04"][key]
    s = same["sequences"]["04"]
    assert 0.05 < s["fix_error_along_rms_m"] < s["fix_error_cross_rms_m"] < 0.5
    with pytest.raises(ConfigError, match="--cross-area"):
        evaluate(_req(tmp_path, kitti_root, cross_area=True, matcher="classical", out=tmp_path / "y"))


def test_taco_plus_on_real_kitti_07_meets_issue_18s_accuracy_and_reports_an_honest_accuracy(tmp_path, kitti_root):
    """The kitti profile end to end on KITTI 07 OXTS (FG2 same-area emulator, seed 0): ATE within 0.5 m at
    no more than 30 fixes/km, and the reported horizontal accuracy (a per-axis 1-sigma) covers the true error
    as a 1-sigma should: 2-sigma coverage between 85 and 98 % (docs/evaluation.md). The coverage fields are in
    results.json per sequence and pooled in the summary, and in the table."""
    res = evaluate(_req(tmp_path, kitti_root, sequences=("07",), estimator="taco+"))
    s = res["sequences"]["07"]
    assert s["ate_m"] <= 0.5 and s["fixes_per_km"] <= 30 and s["lock_losses"] == 0
    assert 0.85 <= s["coverage_2sigma"] <= 0.98
    assert 0.39 <= s["coverage_1sigma"] < s["coverage_2sigma"]
    assert s["coverage_frames"] > 1000 and s["h_acc_median_m"] > 0
    assert res["summary"]["coverage_2sigma"] == s["coverage_2sigma"]
    assert "error within 2 h_acc (2-sigma)" in (tmp_path / "run" / "table.md").read_text()
    # without the calibration the filter's own covariance is reported: far too cautious
    plain = evaluate(_req(tmp_path, kitti_root, sequences=("07",), estimator="taco+", out=tmp_path / "plain",
                          ablations=("no_report_calibration",)))
    p = plain["ablations"]["no_report_calibration"]["sequences"]["07"]
    assert p["ate_m"] == s["ate_m"] and p["coverage_1sigma"] > s["coverage_1sigma"]
