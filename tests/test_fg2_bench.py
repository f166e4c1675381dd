"""Bench section fg2 on the fake FG2 checkout (CPU): its keys, and their absence without a checkout."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

pytest.importorskip("torch", reason="the fg2 extra (torch) is not installed")

from taco_mav.bench import fg2 as bench_fg2  # noqa: E402
from taco_mav.bench import run_bench

FAKE = Path(__file__).parent / "fake_fg2"


def test_fg2_section_keys_on_a_cpu() -> None:
    r = bench_fg2.run(progress=False, checkout=str(FAKE), device="cpu", triggers=2, warmup=0)
    assert 0 < r["fg2_trigger_ms_p50"] <= r["fg2_trigger_ms_p90"]
    assert r["fg2_crop_ms"] == pytest.approx(r["fg2_trigger_ms_p50"] / 5, abs=0.01)
    assert r["fg2_peak_gb"] >= 0 and r["fg2_peak_source"] == "cpu_rss_growth"
    assert r["fg2_device"] == "cpu" and r["fg2_triggers"] == 2 and r["fg2_fast"] and r["fg2_random_weights"]
    assert r["fg2_crop_path"] == "cpu" and 0 < r["fg2_cut_ms_p50"] <= r["fg2_cut_ms_p90"]


def test_fg2_section_with_crops_warped_on_the_device() -> None:
    r = bench_fg2.run(progress=False, checkout=str(FAKE), device="cpu", triggers=2, warmup=1, device_crops=True)
    assert r["fg2_crop_path"] == "device" and 0 < r["fg2_cut_ms_p50"] <= r["fg2_cut_ms_p90"]
    assert 0 < r["fg2_trigger_ms_p50"] and r["fg2_device"] == "cpu"


def test_fg2_keys_absent_without_a_checkout(tmp_path: Path) -> None:
    assert bench_fg2.run(progress=False) == {}
    out = tmp_path / "b.json"
    assert run_bench(out, only=["fg2"], progress=False, options={"fg2": {"device": "cpu"}}) == {}
    assert json.loads(out.read_text()) == {}
