"""Hostile cases of `scheimpflug study` (issue 25): a metric the artefacts cannot measure, draws
that fail, jobs too large to plan, keys given twice, and a sample count too large to render.

Everything but one test is refused at the spec (no rendering, milliseconds) or works on the
analysis of hand-made draw records; the one rendered study is the issue's own (±60 mm on the
focal length, 6 draws on a 4 × 4 binned sensor: 4 draws cannot calibrate, 2 are the same rig).
"""

from __future__ import annotations

import json
import math
import time

import pytest

from scheimpflug.errors import RenderError, StudyError

TOLERANCE = """
[study]
seed = 1
draws = 6
[rig]
preset = "paper"
[tolerance]
"sensor.roll_deg" = 0.05
[artefacts]
kinds = ["ball-bar"]
binning = 4
frames = 5
"""

SWEEP = """
[rig]
preset = "paper"
[sweep]
"laser.tan_phi" = [0.15, 0.2075]
[artefacts]
kinds = []
"""


def _spec(tmp_path, text, kind):
    from sim.study import load_study_spec

    path = tmp_path / f"{kind}.toml"
    path.write_text(text)
    return load_study_spec(path, kind)


def _cli(tmp_path, capsys, text, kind, *extra):
    from scheimpflug.app.cli import main

    (tmp_path / "s.toml").write_text(text)
    t0 = time.perf_counter()
    code = main(["study", kind, str(tmp_path / "s.toml"), "--out", str(tmp_path / "o"), "--quiet", *extra])
    seconds = time.perf_counter() - t0
    out = capsys.readouterr()
    _cli.stdout = out.out
    return code, out.err.strip().splitlines(), seconds


# ------------------------------------------------------------------ a metric the artefacts cannot measure


@pytest.mark.parametrize("change, words", [
    (('kinds = ["ball-bar"]', 'kinds = ["sphere"]'),                           # the issue's case: SD by default
     ["study.metric = 'SD_mm'", "the default", "needs the ball bar", '["sphere"]', "PF_mm, PS_mm"]),
    (("seed = 1", 'seed = 1\nmetric = "PF_mm"'), ["'PF_mm'", "needs the sphere", '["ball-bar"]', "(SD_mm)"]),
    (("seed = 1", 'seed = 1\nmetric = "F_mm"'), ["'F_mm'", "needs the plane"]),
    (("seed = 1", 'seed = 1\nmetric = "part_rms_mm"'), ["'part_rms_mm'", "needs a user part", "artefacts.part"]),
])
def test_a_metric_the_artefacts_cannot_measure_is_one_line_before_anything(tmp_path, capsys, change, words):
    code, err, _ = _cli(tmp_path, capsys, TOLERANCE.replace(*change), "tolerance")
    assert code == 2 and len(err) == 1, err
    assert all(w in err[0] for w in words), err[0]
    assert not (tmp_path / "o").exists()


def test_every_measurable_metric_is_accepted(tmp_path):
    text = TOLERANCE.replace('kinds = ["ball-bar"]', 'kinds = ["sphere", "plane", "ball-bar"]\npart = "cylinder"')
    for metric in ("SD_mm", "PF_mm", "PS_mm", "F_mm", "part_rms_mm"):
        assert _spec(tmp_path, text.replace("seed = 1", f'seed = 1\nmetric = "{metric}"'), "tolerance").metric == metric


def test_a_sweep_of_closed_forms_refuses_a_limit_on_a_metric_it_does_not_measure(tmp_path, capsys):
    from sim.study import run_study

    assert _spec(tmp_path, SWEEP, "sweep").artefacts.kinds == ()          # closed forms only: fine
    for text, word in ((SWEEP.replace("[rig]", '[study]\nmax_error_mm = 0.1\n[rig]'), "study.max_error_mm"),
                       (SWEEP.replace("[rig]", '[study]\nmetric = "PF_mm"\n[rig]'), "study.metric = 'PF_mm'")):
        with pytest.raises(StudyError, match="artefacts.kinds = \\[\\] measures nothing") as e:
            _spec(tmp_path, text, "sweep")
        assert word in str(e.value)
    with pytest.raises(StudyError, match="artefacts.part: .* needs at least one artefact kind"):
        _spec(tmp_path, SWEEP.replace("kinds = []", 'kinds = []\npart = "cylinder"'), "sweep")
    spec = _spec(tmp_path, SWEEP, "sweep")
    with pytest.raises(StudyError, match="--max-error-mm 0.1 limits the SD_mm, which artefacts.kinds = \\[\\]"):
        run_study(spec, tmp_path / "out", max_error_mm=0.1)
    assert not (tmp_path / "out").exists()
    code, err, _ = _cli(tmp_path, capsys, SWEEP, "sweep", "--max-error-mm", "0.1")
    assert code == 2 and len(err) == 1 and "--max-error-mm" in err[0] and not (tmp_path / "o").exists()


# ------------------------------------------------------------------ draws that do not measure (records)


def _records(sd):
    """Hand-made draw records of a one-key study: sd[k] is draw k's SD (None: not measured)."""
    devs = [-0.04, 0.01, 0.01, 0.03, -0.02, -0.02, 0.02, 0.045]      # Saltelli with d = 1 repeats rows
    recs = []
    for k, y in enumerate(sd):
        ok = y is not None and not (isinstance(y, float) and math.isnan(y))
        measured = y is not None
        recs.append({"draw": k, "status": "ok" if measured else "not-measured",
                     "reason": "" if measured else "only 0 usable calibration frame(s)", "seed": 7,
                     "values": {"sensor.roll_deg": devs[k]}, "deviations": {"sensor.roll_deg": devs[k]},
                     "unit": [0.5], "design": {}, "seconds": {"wall": 1.0, "cpu": 1.0},
                     "outputs": None if not measured else {"SD_mm": y if ok else None, "axis_error_mm": 0.001 * k}})
    return recs


def test_draws_without_the_metric_are_counted_named_and_not_ranked(tmp_path):
    from sim.study.analysis import analyse_tolerance

    spec = _spec(tmp_path, TOLERANCE, "tolerance")
    s = analyse_tolerance(spec, _records([None, 0.01, 0.01, None, None, None]), None)
    assert s["draws"] == 6 and s["draws_measured"] == 2 and s["metric_measured"] == 2
    assert [m["draw"] for m in s["metric_missing"]] == [0, 3, 4, 5]
    assert all("usable calibration" in m["reason"] for m in s["metric_missing"])
    d = s["outputs"]["SD_mm"]["distribution"]
    assert (d["n"], d["measured"], d["missing"]) == (1, 2, [0, 3, 4, 5])   # two draws, one rig
    assert d["std"] is None and "a σ needs at least 3" in d["std_note"]      # no σ of 0 from a repeat
    assert s["sensitivity"] == [] and len(s["ranking"]) == 1
    assert s["ranking"][0].startswith("not ranked: 2 of 6 draws measured the SD_mm; not draws 0, 3, 4, 5")
    assert "contributes" not in s["ranking"][0]


def test_a_metric_missing_in_a_measured_draw_is_reported_and_sigma_counts_distinct_rigs(tmp_path):
    from sim.study.analysis import analyse_tolerance

    spec = _spec(tmp_path, TOLERANCE.replace("draws = 6", "draws = 8"), "tolerance")
    sd = [-0.04, 0.01, 0.01, 0.03, -0.02, -0.02, float("nan"), 0.045]       # draw 6 measured, no SD
    s = analyse_tolerance(spec, _records(sd), None)
    assert s["metric_missing"] == [{"draw": 6, "status": "ok", "reason": "measured, but without a SD_mm"}]
    d = s["outputs"]["SD_mm"]["distribution"]
    distinct = [-0.04, 0.01, 0.03, -0.02, 0.045]                            # draws 2 and 5 repeat 1 and 4
    mean = sum(distinct) / 5
    std = math.sqrt(sum((v - mean) ** 2 for v in distinct) / 4)
    assert (d["n"], d["measured"]) == (5, 7) and d["mean"] == pytest.approx(mean, rel=1e-12)
    assert d["std"] == pytest.approx(std, rel=1e-12)
    assert s["ranking"][0].startswith("not ranked: 7 of 8 draws measured the SD_mm; not draws 6 (1 × measured")
    full = analyse_tolerance(spec, _records([v if v == v else 0.02 for v in sd]), None)
    assert full["metric_missing"] == [] and full["sensitivity"][0]["key"] == "sensor.roll_deg"
    assert "the only tolerance, with common noise, 8 draws" in full["ranking"][0]


def test_a_metric_that_never_varies_is_not_ranked_as_100_percent(tmp_path):
    from sim.study.analysis import analyse_tolerance

    s = analyse_tolerance(_spec(tmp_path, TOLERANCE, "tolerance"), _records([0.02] * 6), None)
    assert s["sensitivity"] == [] and "takes one value over every draw" in s["ranking"][0]


def test_a_study_where_no_draw_measured_still_writes_its_report(tmp_path):
    """Every draw not measured: the report says so (it was an internal error in the histograms)."""
    from scheimpflug.app.study_report import write_study_report
    from sim.study import StudyResult
    from sim.study.analysis import analyse_tolerance, table_rows

    spec = _spec(tmp_path, TOLERANCE, "tolerance")
    recs = _records([None] * 6)
    summary = {"kind": "tolerance", "name": spec.name, "planned": 6, "failures": [], "metric": "SD_mm",
               "wall_s": 1.0, "cpu_s_draws": 6.0, "analytic": None, **analyse_tolerance(spec, recs, None)}
    res = StudyResult(tmp_path, spec, recs, table_rows(spec, recs), summary)
    text = write_study_report(res, tmp_path).read_text()
    assert "6 of 6 complete, 0 of 6 draws measured the SD_mm; not draws 0, 1, 2, 3, 4, 5" in text
    assert "not ranked" in text and not (tmp_path / "distributions.png").exists()


def test_a_sweep_names_the_designs_without_its_metric(tmp_path):
    from sim.study.analysis import analyse_sweep

    spec = _spec(tmp_path, SWEEP.replace("kinds = []", 'kinds = ["ball-bar"]'), "sweep")
    base = {"reason": "", "near_mm": 100.0, "far_mm": 300.0, "depth_range_mm": 200.0,
            "distance_resolution_center_mm": 0.2, "height_resolution_center_mm": 0.05}
    rows = [{**base, "draw": 0, "status": "ok", "SD_mm": 0.01},
            {**base, "draw": 1, "status": "ok", "SD_mm": math.nan},
            {**base, "draw": 2, "status": "not-measured", "reason": "outside the field", "SD_mm": math.nan}]
    s = analyse_sweep(spec, rows)
    assert s["measured"] == 1 and [b["draw"] for b in s["best"]] == [0]
    assert s["metric_missing"] == [{"draw": 1, "status": "ok", "reason": "measured, but without a SD_mm"},
                                   {"draw": 2, "status": "not-measured", "reason": "outside the field"}]


@pytest.mark.render
def test_the_focal_length_study_of_the_issue_says_what_it_measured(tmp_path, capsys, variant):
    """±60 mm on f: draws 0, 3, 4, 5 cannot calibrate; 1 = 2 and 4 = 5 are the same rig (Saltelli, d = 1)."""
    text = TOLERANCE.replace('"sensor.roll_deg" = 0.05', '"lens.focal_length_mm" = 60.0')
    code, err, _ = _cli(tmp_path, capsys, text, "tolerance")
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert code == 0 and s["draws"] == 6 and s["metric_measured"] == 2 and s["draws_distinct"] == 4
    assert [m["draw"] for m in s["metric_missing"]] == [0, 3, 4, 5]
    assert s["outputs"]["SD_mm"]["distribution"]["std"] is None and s["sensitivity"] == []
    assert s["ranking"][0].startswith("not ranked: 2 of 6 draws measured the SD_mm; not draws 0, 3, 4, 5")
    assert "analytic propagation gives no first-order share" in s["ranking"][0]
    # the analytic propagation survives the points outside the lens range (f − 2σ < 0): None there
    assert "error" not in s["analytic"]
    assert s["analytic"]["responses"]["lens.focal_length_mm"]["outputs"]["SD_mm"][0] is None
    printed = _cli.stdout + "\n".join(err)
    assert "6 of 6 draws complete, 2 of 6 draws measured the SD_mm; not draws 0, 3, 4, 5" in printed
    report = (tmp_path / "o" / "report.md").read_text()
    assert "6 of 6 complete, 2 of 6 draws measured the SD_mm" in report and "contributes" not in report


# ------------------------------------------------------------------ jobs too large to plan


@pytest.mark.parametrize("kind, change, words", [
    ("sweep", ('"laser.tan_phi" = [0.15, 0.2075]', '"laser.tan_phi" = { range = [0.1, 0.3], steps = 10000 }\n'
                                                   '"lens.f_number" = { range = [4.0, 11.0], steps = 10000 }'),
     ["10,000 × 10,000 = 100,000,000 designs", "limit of 10,000"]),
    ("sweep", ('"laser.tan_phi" = [0.15, 0.2075]', '"laser.tan_phi" = { range = [0.1, 0.3], steps = 100000000 }'),
     ["steps = 100,000,000", "limit of 10,000"]),
    ("sweep", ("[rig]", '[study]\nsampling = "lhs"\ndesigns = 1000000000\n[rig]'),
     ["study.designs = 1,000,000,000", "limit of 10,000"]),
    ("tolerance", ("draws = 6", "draws = 1000000000"), ["study.draws = 1,000,000,000", "limit of 10,000 draws"]),
    ("tolerance", ("frames = 5", "frames = 100000000"), ["artefacts.frames = 100,000,000", "limit of 1,000"]),
    ("tolerance", ("frames = 5", 'frames = 5\npart = "cylinder"\npart_step_deg = 1e-9'),
     ["360,000,000,000 frames per turn", "limit of 10,000"]),
])
def test_a_job_too_large_is_refused_within_a_second_with_its_size(tmp_path, capsys, kind, change, words):
    text = (SWEEP if kind == "sweep" else TOLERANCE).replace(*change)
    if kind == "sweep" and "lhs" in text:
        text = text.replace("[0.15, 0.2075]", "{ range = [0.1, 0.3] }")
    _spec(tmp_path, TOLERANCE if kind == "tolerance" else SWEEP, kind)      # imports warm
    code, err, seconds = _cli(tmp_path, capsys, text, kind)
    assert code == 2 and len(err) == 1 and all(w in err[0] for w in words), err
    assert seconds < 1.0 and not (tmp_path / "o").exists()


def test_a_binning_that_leaves_no_pixel_is_one_line(tmp_path, capsys):
    code, err, _ = _cli(tmp_path, capsys, TOLERANCE.replace("binning = 4", "binning = 1000000"), "tolerance")
    assert code == 2 and len(err) == 1 and "artefacts.binning = 1000000: binning 1000000 leaves no pixel" in err[0]


# ------------------------------------------------------------------ a key given twice


def test_a_swept_key_also_in_rig_set_is_one_error_naming_it(tmp_path):
    text = SWEEP.replace('preset = "paper"', 'preset = "paper"\n[rig.set]\n"laser.tan_phi" = 0.25')
    with pytest.raises(StudyError, match="'laser.tan_phi' is given in \\[rig.set\\] and in \\[sweep\\]"):
        _spec(tmp_path, text, "sweep")
    placed = SWEEP.replace('preset = "paper"', 'preset = "paper"\n[rig.set]\n"sensor.hinge_column" = 3000.0') + \
        "[placement]\nnear_mm = 300.0\nfar_mm = 600.0\n"
    with pytest.raises(StudyError, match="'sensor.hinge_column' is given in \\[rig.set\\] but \\[placement\\] solves"):
        _spec(tmp_path, placed, "sweep")


def test_a_toleranced_key_in_rig_set_is_the_nominal_it_is_drawn_around(tmp_path):
    """Not an override: [rig.set] fixes the design, [tolerance] the deviations around it."""
    from sim.study import plan_draws

    text = TOLERANCE.replace('preset = "paper"', 'preset = "paper"\n[rig.set]\n"sensor.roll_deg" = 0.3')
    plans = plan_draws(_spec(tmp_path, text, "tolerance"))
    assert all(p.values["sensor.roll_deg"] == pytest.approx(0.3 + p.deviations["sensor.roll_deg"], abs=1e-12)
               for p in plans)
    assert all(abs(p.values["sensor.roll_deg"] - 0.3) <= 0.05 for p in plans)


# ------------------------------------------------------------------ samples per row


def test_the_laser_sample_limit_is_the_memory_budget():
    from sim.render_limits import (
        LASER_MEMORY_BUDGET_BYTES,
        check_laser_samples,
        laser_memory_bytes,
        max_samples_per_row,
    )

    for rows, bounces in ((1936, 1), (1936, 3), (242, 1), (30, 2)):
        top = max_samples_per_row(rows, bounces)
        assert laser_memory_bytes(top, rows, bounces) <= LASER_MEMORY_BUDGET_BYTES
        assert laser_memory_bytes(top + 1, rows, bounces) > LASER_MEMORY_BUDGET_BYTES
        check_laser_samples(top, rows, bounces)
        with pytest.raises(RenderError, match=f"at most spp = {top:,} for {rows} rows"):
            check_laser_samples(top + 1, rows, bounces)
    check_laser_samples(32, 1936, 8)                                   # the default fits at full size


def test_a_study_spp_too_large_is_refused_at_the_spec(tmp_path):
    with pytest.raises(StudyError, match="artefacts.spp = 100000000: .* 484 rows .* at most artefacts.spp = "):
        _spec(tmp_path, TOLERANCE.replace("frames = 5", "frames = 5\nspp = 100000000"), "tolerance")
    assert _spec(tmp_path, TOLERANCE.replace("frames = 5", "frames = 5\nspp = 64"), "tolerance").artefacts.spp == 64


def test_render_spp_too_large_is_one_line_naming_the_limit(tmp_path, capsys):
    from scheimpflug.app.cli import main

    t0 = time.perf_counter()
    code = main(["render", "calibration", "--out", str(tmp_path / "o"), "--binning", "8", "--steps", "1",
                 "--spp", "100000000", "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and time.perf_counter() - t0 < 5
    assert "--spp 100000000" in err[0] and "242 rows" in err[0] and "at most --spp 1,574,183" in err[0]
    assert not (tmp_path / "o").exists()
    # within the old --spp cap (10⁶) but 39 GB at full size (it was started and killed for memory)
    assert main(["render", "calibration", "--out", str(tmp_path / "o"), "--steps", "1", "--spp", "1000000",
                 "--quiet"]) == 2
    assert "1936 rows" in capsys.readouterr().err and not (tmp_path / "o").exists()


@pytest.mark.render
def test_the_renderer_refuses_too_many_samples_before_allocating(variant, paper_rig):
    from scheimpflug.model.binning import binned_rig
    from sim.render import Renderer, RenderSettings
    from sim.scenarios import calibration_scenario
    from sim.scene import SimScene

    rig = binned_rig(paper_rig, 8)
    scene = SimScene(calibration_scenario(rig, steps=1, truth_pixels_every=0).assembly.parts)
    t0 = time.perf_counter()
    with pytest.raises(RenderError, match="RenderSettings.samples_per_row = 100000000: .* 242 rows"):
        Renderer(rig, scene, RenderSettings(samples_per_row=10**8))
    assert time.perf_counter() - t0 < 5
