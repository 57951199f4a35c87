"""runtime/bench/flare_bench.py (issue 13's flare benchmark) on tiny settings: the rates
and ratios are the renders' own stats in the interleaved order, the baseline ratio uses
lensrt-bench's JSON (skipped without it), the error's interpolation and extrapolation
agree with closed forms, and a whole run writes flares.json with positive, finite figures."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "runtime" / "bench"))

import flare_bench as fb  # noqa: E402  (needs the path above)

DIRECT = fb.FOLDER / "lens0001.table"


def fake_lensrt_json(path: Path, rate: float) -> Path:
    """The part of lensrt-bench's JSON the benchmark reads (its real structure)."""
    path.write_text(json.dumps({"f_number": 8, "baseline_threads": 2, "date": "x",
                                "baseline_splats_per_second": 1.0,  # not f/8's entry
                                "per_f_number": {"8": {"baseline_splats_per_second": rate}},
                                "baseline": {"algorithm": "scalar"}}))
    return path


def test_splat_rates_are_the_renders_stats_in_interleaved_order(rt, tmp_path):
    ghosts = fb.load_ghosts(fb.FOLDER)[:2]  # two suffice (and keep the test short)
    assert len(ghosts) >= 1
    base = fb.baseline_rate(fake_lensrt_json(tmp_path / "lensrt.json", 2.5e5))
    assert base["splats_per_second"] == 2.5e5  # f/8's entry, not the top-level one
    samples, repeats, stride = 64, 2, 120
    res = fb.splat_rates(rt, DIRECT, ghosts, stride, samples, repeats, base)
    assert res["rendered_resolution"] == [12, 9]
    recs = res["renders"]
    labels = [g["label"] for g in ghosts]
    # direct, g1, direct, g2, ..., direct, repeats times over (shared direct renders)
    expect = ["direct"] + [x for _ in range(repeats) for g in labels for x in (g, "direct")]
    assert [r["image"] for r in recs] == expect
    for r in recs:
        # Every pixel (dark ones too) of every wavelength gets every sample
        assert r["splats"] == 12 * 9 * fb.WAVELENGTHS * samples
        assert r["seconds"] > 0
        assert r["splats_per_second"] == pytest.approx(r["splats"] / r["seconds"], rel=1e-12)
    d_rates = [r["splats_per_second"] for r in recs if r["image"] == "direct"]
    assert res["direct"]["splats_per_second"] == pytest.approx(np.median(d_rates), rel=1e-12)
    assert res["direct"]["ratio_vs_baseline"] == pytest.approx(np.median(d_rates) / 2.5e5)
    for k, label in enumerate(labels):
        g = res["ghosts"][label]
        # Each ghost render over the mean of the direct renders right before and after it
        ratios = []
        for i, r in enumerate(recs):
            if r["image"] == label:
                ratios.append(r["splats_per_second"] / (0.5 * (
                    recs[i - 1]["splats_per_second"] + recs[i + 1]["splats_per_second"])))
        assert len(ratios) == repeats
        assert g["ratio_vs_direct"] == pytest.approx(np.median(ratios), rel=1e-12)
        rate = np.median([r["splats_per_second"] for r in recs if r["image"] == label])
        assert g["splats_per_second"] == pytest.approx(rate, rel=1e-12)
        assert g["ratio_vs_baseline"] == pytest.approx(rate / 2.5e5, rel=1e-12)
        for v in (g["ratio_vs_direct"], g["ratio_vs_baseline"]):
            assert math.isfinite(v) and v > 0
        assert g["side"] == ghosts[k]["side"]
    # The whole flare: one direct and one render per ghost, over their median seconds
    f = res["flare"]
    assert f["splats"] == (1 + len(labels)) * 12 * 9 * fb.WAVELENGTHS * samples
    secs = res["direct"]["seconds"] + sum(res["ghosts"][x]["seconds"] for x in labels)
    assert f["splats_per_second"] == pytest.approx(f["splats"] / secs, rel=1e-12)
    assert f["ratio_vs_direct"] == pytest.approx(
        f["splats_per_second"] / res["direct"]["splats_per_second"], rel=1e-12)


def test_baseline_absent_is_skipped_not_failed(rt, tmp_path):
    base = fb.baseline_rate(tmp_path / "missing.json")
    assert "not found" in base["skipped"]
    res = fb.splat_rates(rt, DIRECT, fb.load_ghosts(fb.FOLDER)[:1], 120, 16, 1, base)
    assert res["direct"]["ratio_vs_baseline"] is None
    assert all(g["ratio_vs_baseline"] is None for g in res["ghosts"].values())


def steps_of(law, secs, ns):
    return [dict(samples=n, error_one=law(n), seconds=[secs(n), secs(n)]) for n in ns]


def test_error_steps_close_in_and_interpolate_a_power_law_exactly():
    """Sobol-like error 2/N and seconds 0.5 + 1e-3 N: from 4096 the 1/sqrt(N) law asks for
    2^round(log2 4096 (4.9e-4/0.01)^2) = 2^4 -> MIN_ERROR_SAMPLES (64); then the slope
    measured between 4096 and 64 (-1) asks for 200 -> 256; then 200 again, measured: stop."""
    law, secs, t = (lambda n: 2.0 / n), (lambda n: 0.5 + 1e-3 * n), 0.01
    steps = steps_of(law, secs, [4096])
    assert fb.next_samples(steps, t, 1 << 17) == fb.MIN_ERROR_SAMPLES
    steps = steps_of(law, secs, [4096, 64])
    assert fb.next_samples(steps, t, 1 << 17) == 256
    steps = steps_of(law, secs, [4096, 64, 256])
    assert fb.next_samples(steps, t, 1 << 17) is None
    est = fb.estimate_target(steps, t)
    # A power law is a line in log-log: interpolation between the nearest pairs on both
    # sides (64 above 1%, 256 below) is exact (N = 200), and so is the affine seconds
    assert est["samples_to_target"] == pytest.approx(200.0, rel=1e-12)
    assert est["seconds_to_target"] == pytest.approx(secs(200.0), rel=1e-12)
    assert est["method"] == "interpolated between N = 64 and 256"
    # Neighbours bracketing the target end the search even when the slope asks for more
    steps = steps_of(lambda n: 0.02 * (128 / n) ** 0.3, secs, [128, 256])
    assert law(128) > t and 0.02 * 0.5 ** 0.3 > t  # both above: not bracketed, go on
    assert fb.next_samples(steps, t, 1 << 17) is not None
    steps = steps_of(law, secs, [128, 256])  # 1.6% and 0.78%
    assert fb.next_samples(steps, t, 1 << 17) is None


def test_error_one_side_only_uses_the_sqrt_law():
    """A ghost that the largest N does not bring to 1%: N e^2 / t^2 from the pair nearest
    the target, seconds affine through the two largest N (or proportional with one)."""
    law, secs, t = (lambda n: 30.0 / math.sqrt(n)), (lambda n: 0.5 + 1e-4 * n), 0.01
    one = fb.estimate_target(steps_of(law, secs, [4096]), t)
    assert one["samples_to_target"] == pytest.approx(4096 * (30 / 64 / t) ** 2, rel=1e-12)
    assert one["seconds_to_target"] == pytest.approx(
        secs(4096) * one["samples_to_target"] / 4096, rel=1e-12)
    steps = steps_of(law, secs, [4096, 1 << 17])
    assert fb.next_samples(steps, t, 1 << 17) is None  # capped at the largest N
    two = fb.estimate_target(steps, t)
    assert two["samples_to_target"] == pytest.approx(9e6, rel=1e-12)  # (30 / 0.01)^2
    assert two["seconds_to_target"] == pytest.approx(secs(9e6), rel=1e-12)
    assert two["from_samples"] == 1 << 17
    # The measured slope of a 1/sqrt(N) law is -1/2: the same N
    assert two["measured_slope"] == pytest.approx(-0.5, rel=1e-12)
    assert two["samples_to_target_measured_slope"] == pytest.approx(9e6, rel=1e-9)
    # A faster law (Sobol on a smooth image, 300 / N): the measured slope finds N = 3e4
    fast = fb.estimate_target(steps_of(lambda n: 300.0 / n, secs, [4096, 8192]), t)
    assert fast["samples_to_target"] == pytest.approx(8192 * (300 / 8192 / t) ** 2)
    assert fast["samples_to_target_measured_slope"] == pytest.approx(3e4, rel=1e-9)
    assert fast["seconds_to_target_measured_slope"] == pytest.approx(secs(3e4), rel=1e-9)
    # Errors that barely fall (a floor-dominated ghost: 0.80 then 0.79 at 8x the samples):
    # no slope figure (it would ask for 1e100 samples or overflow), the 1/sqrt(N) one stays
    flat = fb.estimate_target([dict(samples=4096, error_one=0.80, seconds=[1.0, 1.0]),
                               dict(samples=32768, error_one=0.79, seconds=[8.0, 8.0])], t)
    assert "measured_slope" not in flat
    assert flat["samples_to_target"] == pytest.approx(32768 * 79.0 ** 2)
    # Seconds that fell with N (a loaded machine): no affine line, proportional to N
    noisy = steps_of(law, lambda n: 5.0 - 1e-5 * n, [4096, 1 << 17])
    three = fb.estimate_target(noisy, t)
    assert three["seconds_to_target"] == pytest.approx(
        (5.0 - 1e-5 * (1 << 17)) * 9e6 / (1 << 17), rel=1e-12)


def test_pair_error_of_one_seed_twice_is_zero(rt):
    """Same seed, same samples: the two renders agree bit for bit (the error estimate is
    the seeds' difference, nothing else); other seeds differ."""
    lens = rt.load(DIRECT)
    center = rt.image_point(lens, fb.FIELD, 580.0)
    scene = fb.window_scene(center, 0.04, 16)
    same = fb.pair_error(rt, lens, scene, 64, seeds=(3, 3))
    other = fb.pair_error(rt, lens, scene, 64, seeds=(3, 4))
    assert same["error_one"] == 0.0
    assert other["error_one"] > 0.0
    assert other["error_one"] == pytest.approx(math.sqrt(2) * other["error_mean_of_two"])


def test_tiny_run_writes_flares_json(tmp_path, monkeypatch):
    monkeypatch.setattr(fb, "MAX_STEPS", 2)
    ghosts = fb.load_ghosts(fb.FOLDER)[:2]  # the first two of the kept ghosts, for time
    monkeypatch.setattr(fb, "load_ghosts", lambda folder: [dict(g) for g in ghosts])
    out = tmp_path / "bench"
    assert fb.main(["--out", str(out), "--library", str(fb.LIBRARY), "--stride", "120",
                    "--samples", "32", "--error-pixels", "16",
                    "--error-samples", "64", "--max-error-samples", "256", "--rays", "100",
                    "--fit-ghost", "none"]) == 0
    res = json.loads((out / "flares.json").read_text())["flares"]
    assert res["ghosts"] == [g["label"] for g in ghosts]
    sp = res["splats"]
    assert "skipped" in sp["baseline"]  # no lensrt.json in out
    # Default repeats: 3 for 2 ghosts, fewer with more (at most MAX_SPLAT_RENDERS renders)
    assert sp["repeats"] == max(1, min(3, (fb.MAX_SPLAT_RENDERS - 1) // (2 * len(ghosts))))
    assert len(sp["renders"]) == 1 + 2 * len(ghosts) * sp["repeats"]
    assert res["error"]["max_samples"] == 256
    for r in [res["error"]["direct"], *res["error"]["ghosts"].values()]:
        if r.get("seconds_to_target") is not None:
            assert r["rough"] == (r["from_error"] > fb.ROUGH_ERROR)
    assert set(sp["ghosts"]) == set(res["ghosts"])
    for g in sp["ghosts"].values():
        assert math.isfinite(g["ratio_vs_direct"]) and g["ratio_vs_direct"] > 0
    er = res["error"]
    d = er["direct"]
    assert d["seconds_to_target"] > 0 and math.isfinite(d["seconds_to_target"])
    assert d["steps"][0]["samples"] == 64 and len(d["steps"]) <= 2
    assert d["from_samples"] in [st["samples"] for st in d["steps"]]
    for g in er["ghosts"].values():
        if "skipped" not in g and g["seconds_to_target"] is not None:
            assert math.isfinite(g["ratio_vs_direct"]) and g["ratio_vs_direct"] > 0
    ft = res["fitting"]
    assert ft["enumeration"]["ghosts"] == 91  # 0001: pairs of its 14 non-stop surfaces
    assert ft["fit_live"] is None
    rec = ft["recorded"]
    assert rec["fit_seconds"] == pytest.approx(sum(g["fit_seconds"] for g in ghosts))
    assert rec["total_seconds"] == pytest.approx(
        rec["fit_seconds"] + sum(g["exact_seconds"] for g in ghosts))
    assert rec["total_seconds"] > 0


def test_fit_choice_and_its_report(capsys):
    """--fit-ghost: all (every kept ghost live, the default), one ghost I-J, or none; the
    line for "all" sums the live fits with the enumeration against the 5-minute target."""
    assert fb.parse_ghost("all") == "all" and fb.parse_ghost("none") is None
    assert fb.parse_ghost("4-8") == (4, 8)
    ft = dict(enumeration=dict(ghosts=91, seconds=10.0), target_seconds=300.0,
              fit_live=dict(ghost="all", seconds=200.0,
                            per_ghost={"0-2": dict(seconds=50.0), "4-8": dict(seconds=150.0)}),
              recorded=dict(kept=2, fit_seconds=1.0, trust_exact_seconds=2.0,
                            total_seconds=3.0),
              recorded_plus_live_enumeration_seconds=13.0)
    fb.report_fitting(ft)
    out = capsys.readouterr().out
    assert "all 2 kept ghosts" in out and "0-2 50 s, 4-8 150 s" in out
    assert "with the enumeration 210.0 s against the target 300 s (0.70 of it)" in out
