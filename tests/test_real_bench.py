"""The real-imagery bench (bench/real.py): the matcher and the answer check as the daemon runs them, on the real
pairs in ../shared (skipped where absent) and on synthetic pairs made the same way."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from taco_mav.bench import real
from taco_mav.config import load_profile, replace_in
from taco_mav.core.params import AnswerParams

REAL_PAIRS = Path(__file__).resolve().parents[2] / "shared" / "data" / "real_pairs"
PLACES = 4  # of the 12 Canberra places: 32 views, each asked on its own map and on another place's


def need_real() -> Path:
    if not (REAL_PAIRS / "cvact" / "pairs.json").is_file():
        pytest.skip(f"real pairs not found at {REAL_PAIRS} (expected ../shared/data/real_pairs beside the repo)")
    return REAL_PAIRS


def test_on_real_imagery_nothing_wrong_is_accepted_and_the_unchecked_matcher_reproduces_the_failure() -> None:
    root = need_real()
    rover = load_profile("ardupilot_rover")
    tries, keys = real.evaluate_real(root, rover, places_per_set=PLACES)
    assert keys["real_tries"] == 8 * PLACES and keys["real_places"] == PLACES
    # the classical matcher cannot read these scenes (the best answer ~24 m off, the prior ~6 m; docs/matchers.md)
    assert keys["real_within_3m_share"] <= 0.1
    assert keys["real_median_error_m"] > 2.0 * keys["real_median_prior_error_m"]
    assert 4.0 <= keys["real_median_prior_error_m"] <= 8.0
    # the answer check: nothing accepted, or what is accepted right; nothing on another place's map
    assert keys["real_accepted_precision"] is None or keys["real_accepted_precision"] >= 0.95
    assert keys["real_wrong_map_accepted_share"] <= 0.01
    # without the check a lost taco+ takes confidently wrong answers as relocalisation candidates (all 12 places:
    # 3 % of the views, every one 14-46 m off, and 2 % on another place's map; these 4 places: 2 of 32 and 1)
    bare = replace_in(rover, "answer", AnswerParams())
    _, unchecked = real.evaluate_real(root, bare, places_per_set=PLACES)
    assert unchecked["real_accepted_share"] > 0.0 and unchecked["real_accepted_precision"] == 0.0
    assert unchecked["real_wrong_map_accepted_share"] > 0.0
    # the same seed gives the same figures
    assert real.evaluate_real(root, rover, places_per_set=PLACES)[1] == keys


def test_on_synthetic_pairs_made_the_same_way_the_right_answers_are_kept() -> None:
    _, keys = real.evaluate_synthetic(load_profile("ardupilot_rover"), places=3)
    assert keys["synthetic_pairs_tries"] == 24
    assert keys["synthetic_pairs_within_3m_share"] >= 0.95
    assert keys["synthetic_pairs_median_error_m"] <= 1.0
    assert keys["synthetic_pairs_accepted_share"] >= 0.9 and keys["synthetic_pairs_accepted_precision"] == 1.0


def test_the_bench_command_names_a_folder_without_sets(tmp_path: Path) -> None:
    out = tmp_path / "bench.json"
    proc = subprocess.run([sys.executable, "-m", "taco_mav.cli", "bench", "--only", "real", "--real-pairs",
                           str(tmp_path), "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 1, proc.stderr
    assert f"{tmp_path}: no set" in proc.stderr
    assert not out.exists() or "real_tries" not in json.loads(out.read_text())
