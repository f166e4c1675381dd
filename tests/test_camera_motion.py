"""Offline taco+ on a camera drive takes the camera's speed as the daemon does (evaluation/camera_motion.py): a
real synthetic world (rendered frames, GeoTIFF mosaic), the real GroundMotion correlation on its frames."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from taco_mav.config import Estimator, load_profile, replace_in
from taco_mav.datasets.synthetic import build_world, load_world
from taco_mav.evaluation.runner import run_drive


@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory):
    return load_world(build_world(tmp_path_factory.mktemp("motion") / "w", seed=3, length_km=0.3, progress=False))


def _run(drive, camera_speed: bool):  # noqa: ANN001
    prof = replace_in(load_profile("synthetic"), "estimator", Estimator.TACO_PLUS)
    return run_drive(drive, replace_in(prof, "plus.camera_speed", camera_speed))


def _ate(run) -> float:  # noqa: ANN001
    return float(np.sqrt(np.mean(np.sum((run.online_xy - run.truth_xy) ** 2, axis=1))))


def test_offline_taco_plus_uses_the_cameras_speed_every_half_second_and_repeats_exactly(drive) -> None:
    """One measurement per 0.5 s of the drive, nearly all used (flat ground, no lead car); the online track of a
    second run is identical; the estimate stays within a metre. (With the camera's speed the filter's covariance
    grows slower, so on this flat world fewer fixes are asked: 8 against 18, ATE 0.77 against 0.39 m, as the
    live daemon, which always fed it, does.)"""
    on = _run(drive, True)
    counts = on.extra["camera_motion"]
    due = (on.t[-1] - on.t[0]) / 0.5
    assert sum(counts.values()) >= 0.9 * due, counts
    assert counts.get("used", 0) >= 0.8 * due, counts
    again = _run(drive, True)
    np.testing.assert_array_equal(on.online_xy, again.online_xy)
    off = _run(drive, False)
    assert off.extra["camera_motion"] == {}
    assert _ate(on) <= 1.0, _ate(on)
    assert _ate(off) <= 1.0, _ate(off)


def test_paper_mode_and_image_less_matchers_take_no_camera_speed(drive) -> None:
    """Paper mode has no speed state; the emulator needs no frames: neither measures ground motion."""
    paper = run_drive(drive, replace_in(load_profile("synthetic"), "estimator", Estimator.PAPER))
    assert paper.extra["camera_motion"] == {}
    emu = replace_in(replace_in(load_profile("synthetic"), "estimator", Estimator.TACO_PLUS), "matcher", "emulator")
    assert run_drive(drive, emu).extra["camera_motion"] == {}


def test_a_camera_that_sees_too_little_ground_runs_without_its_speed(drive, caplog) -> None:  # noqa: ANN001
    """A bonnet over all but the top 5 rows (`classical.ego_mask_rows`): the ground-motion band cannot be placed,
    so the run goes on without the camera's speed and says why in one warning (the daemon does the same)."""
    prof = replace_in(replace_in(load_profile("synthetic"), "estimator", Estimator.TACO_PLUS),
                      "classical.ego_mask_rows", 370)
    with caplog.at_level(logging.WARNING, logger="taco_mav.evaluation.runner"):
        run = run_drive(drive, prof)
    assert run.extra["camera_motion"] == {}
    assert "camera speed off (plus.camera_speed): ground motion: the camera sees no ground" in caplog.text
    assert len(run.online_xy) == len(run.truth_xy) and np.isfinite(run.online_xy).all()
