"""`scheimpflug study`: SALib wiring on known functions, spec errors, closed-form sweeps, the roll
tolerance against the analytic propagation, ranking, 1 vs 2 workers and kill/resume.

The rendered tests use a 4 × 4 binned sensor, the ball bar alone (5 frames per sphere
crossing) and a handful of draws; the SALib and spec tests do not render.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from scheimpflug.errors import StudyError

ROOT = Path(__file__).resolve().parents[1]


# ------------------------------------------------------------------ SALib wiring (no twin)


def test_sobol_indices_of_a_known_additive_function():
    """Y = 3·x1 + 2·x2 + 0·x3, x1 uniform on ±1 (variance 1/3), x2 normal σ = 0.5, x3 uniform:
    V = 9/3 + 4·0.25 = 4, so S1 = ST = (0.75, 0.25, 0)."""
    from scheimpflug.sensitivity import deviation_from_unit, sobol_indices, unit_sample

    q = unit_sample("sobol", 3, 1024 * 5, seed=7)
    assert q.shape == (1024 * 5, 3)
    x1 = deviation_from_unit(q[:, 0], "uniform", 1.0)
    x2 = deviation_from_unit(q[:, 1], "normal", 0.5)
    x3 = deviation_from_unit(q[:, 2], "uniform", 4.0)
    y = 3 * x1 + 2 * x2 + 0 * x3
    idx = {s.key: s for s in sobol_indices(["a", "b", "c"], y, seed=1)}
    for key, exact in (("a", 0.75), ("b", 0.25), ("c", 0.0)):
        assert abs(idx[key].first_order - exact) < 0.03, (key, idx[key])
        assert abs(idx[key].total - exact) < 0.03, (key, idx[key])
    assert unit_sample("sobol", 3, 1024 * 5, seed=7).tolist() == q.tolist()       # seeded


def test_morris_screening_of_a_linear_function_and_the_ranking():
    """Y = 3·x1 + 1·x2 with x = 2q − 1 (uniform ±1): every elementary effect in unit
    coordinates is exactly 6 and 2, so μ* = (6, 2)."""
    from scheimpflug.sensitivity import deviation_from_unit, morris_indices, rank_indices, unit_sample

    q = unit_sample("morris", 2, 30, seed=3)
    assert q.shape == (10 * 3, 2)
    y = 3 * deviation_from_unit(q[:, 0], "uniform", 1.0) + deviation_from_unit(q[:, 1], "uniform", 1.0)
    idx = rank_indices(morris_indices(["weak", "strong"][::-1], q, y))
    assert [s.key for s in idx] == ["strong", "weak"]
    assert idx[0].mu_star == pytest.approx(6.0, rel=1e-9) and idx[1].mu_star == pytest.approx(2.0, rel=1e-9)
    assert idx[0].first_order is None


def test_linear_shares_pareto_front_and_too_few_draws():
    from scheimpflug.model.design import pareto_front
    from scheimpflug.sensitivity import linear_shares, unit_sample

    assert linear_shares([2.0, 1.0], [1.0, 2.0]).tolist() == [0.5, 0.5]
    # (benefit, cost): 1 dominates 0 (more range, same error), 3 is dominated by 1
    assert pareto_front([100, 200, 300, 150], [1.0, 1.0, 2.0, 3.0]).tolist() == [1, 2]
    with pytest.raises(ValueError, match="needs at least 8 draws"):
        unit_sample("sobol", 2, 7, seed=0)


# ------------------------------------------------------------------ specs


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


def _spec(tmp_path, text, kind):
    from sim.study import load_study_spec

    path = tmp_path / f"{kind}.toml"
    path.write_text(text)
    return load_study_spec(path, kind)


@pytest.mark.parametrize("change, message", [
    (('"sensor.roll_deg" = 0.05', '"sensor.rol_deg" = 0.05'), "did you mean 'sensor.roll_deg'"),
    (('"sensor.roll_deg" = 0.05', '"stage.straightness_warp_um" = 1.0'),
     "'stage.straightness_warp_um' is not a key of this rig"),
    (("seed = 1", "seed = 1\nsamples = 3"), "unknown key 'samples' in [study]"),
    (('"sensor.roll_deg" = 0.05', '"sensor.roll_deg" = -0.05'), "a half-width must be > 0"),
    (('"sensor.roll_deg" = 0.05', '"sensor.columns" = 2'), "an integer key cannot be toleranced"),
    (("draws = 6", "draws = 5"), "needs at least 6 draws"),
    (('"sensor.roll_deg" = 0.05', '"sensor.roll_deg" = 0.05\n[sweep]\n"laser.tan_phi" = [0.2]'),
     "[sweep] belongs in a sweep spec"),
    (('kinds = ["ball-bar"]', 'kinds = ["ball"]'), "artefacts.kinds = 'ball': unknown"),
    (('"sensor.roll_deg" = 0.05', '"laser.tan_phi" = 10.0'), "is not a possible rig: [laser] tan_phi"),
])
def test_bad_tolerance_specs_are_one_error_naming_the_key(tmp_path, change, message):
    with pytest.raises(StudyError) as err:
        _spec(tmp_path, TOLERANCE.replace(*change), "tolerance")
    assert message in str(err.value)


def test_rig_set_takes_the_twin_tables_strings_and_booleans_of_the_same_type(tmp_path):
    text = TOLERANCE.replace('preset = "paper"', 'preset = "paper"\n[rig.set]\n"twin.speckle_model" = "sensor"\n'
                             '"twin.subsurface" = true\n"laser.speckle_contrast" = 0.5')
    rig = _spec(tmp_path, text, "tolerance").base_rig()
    assert (rig.twin.speckle_model, rig.twin.subsurface, rig.laser.speckle_contrast) == ("sensor", True, 0.5)
    with pytest.raises(StudyError, match=r"'twin.speckle_model' = 1.0: the rig's value is 'surface' \(str\)"):
        _spec(tmp_path, text.replace('"twin.speckle_model" = "sensor"', '"twin.speckle_model" = 1.0'), "tolerance")
    with pytest.raises(StudyError, match=r"'laser.speckle_contrast' = 'high': the rig's value is"):
        _spec(tmp_path, text.replace("= 0.5", '= "high"'), "tolerance")
    with pytest.raises(StudyError, match="speckle_model"):
        _spec(tmp_path, text.replace('"sensor"', '"film"'), "tolerance")


def test_impossible_sweep_design_names_the_design_and_key(tmp_path):
    text = '[rig]\npreset = "paper"\n[sweep]\n"laser.tan_phi" = [0.2, 3.0]\n[artefacts]\nkinds = []\n'
    with pytest.raises(StudyError, match=r"design 1 \(laser.tan_phi = 3\) is not a possible rig: \[laser\] tan_phi"):
        _spec(tmp_path, text, "sweep")
    with pytest.raises(StudyError, match="range .* is reversed"):
        _spec(tmp_path, text.replace("[0.2, 3.0]", "{ range = [0.3, 0.1] }"), "sweep")


def test_cli_bad_spec_is_one_line_with_status_2(tmp_path, capsys):
    from scheimpflug.app.cli import main

    (tmp_path / "s.toml").write_text(TOLERANCE.replace('"sensor.roll_deg"', '"sensor.rol_deg"'))
    assert main(["study", "tolerance", str(tmp_path / "s.toml"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "sensor.rol_deg" in err[0] and not (tmp_path / "o").exists()


def test_tolerance_draws_are_seeded_and_magnitudes_are_folded(tmp_path):
    from sim.study import plan_draws

    text = TOLERANCE.replace("draws = 6", "draws = 16").replace(
        '"sensor.roll_deg" = 0.05', '"sensor.roll_deg" = 0.05\n"stage.axis_tilt_deg" = { normal = 0.02 }')
    spec = _spec(tmp_path, text, "tolerance")
    a, b = plan_draws(spec), plan_draws(spec)
    assert [p.rig for p in a] == [p.rig for p in b] and len(a) == 16
    assert spec.tolerances[1].magnitude and all(p.deviations["stage.axis_tilt_deg"] >= 0 for p in a)
    assert all(abs(p.deviations["sensor.roll_deg"]) <= 0.05 for p in a)
    assert len({p.seed for p in a}) == 1                                     # common noise
    other = _spec(tmp_path, text.replace("seed = 1", "seed = 2"), "tolerance")
    assert [p.unit for p in plan_draws(other)] != [p.unit for p in a]


# ------------------------------------------------------------------ sweeps


def test_tan_phi_sweep_reproduces_the_closed_forms(tmp_path):
    """Ranges and resolutions of each design from docs/explanation/design-notes.md §3, computed here independently."""
    from sim.study import load_study_spec, run_study

    (tmp_path / "s.toml").write_text('[rig]\npreset = "paper"\n[sweep]\n"laser.tan_phi" = [0.1, 0.2075, 0.3]\n'
                                     '[artefacts]\nkinds = []\n')
    res = run_study(load_study_spec(tmp_path / "s.toml", "sweep"), tmp_path / "out")
    f, d, p, uh, n, rows = 55.0, 150.0, 5.86e-3, 3196.0, 1216, 1936
    for row, t in zip(res.rows, (0.1, 0.2075, 0.3)):
        beta = math.atan(f / (d - f * t))
        cos_phi = 1 / math.hypot(1, t)
        F2 = -f * f / (p * cos_phi * math.sin(beta))
        C = f / math.sin(beta)
        D0, D1 = F2 / (0 - uh), F2 / (n - 1 - uh)
        uc = n // 2
        assert row["rig.laser.tan_phi"] == t and row["status"] == "ok"
        assert row["tilt_deg"] == pytest.approx(math.degrees(beta), rel=1e-12)
        assert row["near_mm"] == pytest.approx(D0 + f / cos_phi, rel=1e-12)
        assert row["far_mm"] == pytest.approx(D1 + f / cos_phi, rel=1e-12)
        assert row["depth_range_mm"] == pytest.approx(D1 - D0, rel=1e-12)
        assert row["distance_resolution_center_mm"] == pytest.approx(abs(F2) / (uc - uh) ** 2, rel=1e-12)
        assert row["height_resolution_center_mm"] == pytest.approx(C / abs(uc - uh), rel=1e-12)
        assert row["height_range_far_mm"] == pytest.approx(C * rows / abs(n - 0.5 - uh), rel=1e-12)
    import pyarrow.parquet as pq

    assert pq.read_table(tmp_path / "out" / "draws.parquet").num_rows == 3
    assert (tmp_path / "out" / "draws.csv").read_text().count("\n") == 4
    best = res.summary["best"]                       # closed forms only: finest distance resolution first
    assert [b["draw"] for b in best] == sorted(range(3), key=lambda i: res.rows[i]["distance_resolution_center_mm"])


def test_a_design_that_cannot_see_the_artefact_is_a_row_not_a_crash(tmp_path, capsys):
    from scheimpflug.app.cli import main

    (tmp_path / "s.toml").write_text('[rig]\npreset = "paper"\n[rig.set]\n"stage.axis_mm" = 4000.0\n'
                                     '[sweep]\n"laser.tan_phi" = [0.2075]\n[artefacts]\nkinds = ["ball-bar"]\n'
                                     'binning = 8\n')
    assert main(["study", "sweep", str(tmp_path / "s.toml"), "--out", str(tmp_path / "o"), "--json",
                 "--quiet"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["measured"] == 0 and out["not_measured"][0]["status"] == "not-measured"
    assert "outside the field" in out["not_measured"][0]["reason"]
    assert "not-measured" in (tmp_path / "o" / "report.md").read_text()


# ------------------------------------------------------------------ tolerance studies (rendered)


@pytest.mark.render
@pytest.mark.slow
def test_roll_tolerance_matches_the_analytic_propagation(tmp_path, capsys):
    """Sensor roll alone: the calibration bias per degree of roll (sign and size) and the
    sensitivities of SD and of the axis, Monte Carlo slope against the analytic Jacobian, within 20 %."""
    from scheimpflug.app.cli import main

    (tmp_path / "s.toml").write_text(TOLERANCE)
    assert main(["study", "tolerance", str(tmp_path / "s.toml"), "--out", str(tmp_path / "o"), "--json",
                 "--quiet"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["draws"] == 6 and out["sensitivity"][0]["key"] == "sensor.roll_deg"
    assert {"key", "first_order", "total"} <= set(out["sensitivity"][0])
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    for name in ("err.hinge_v_px", "err.hinge_u_px", "SD_mm", "axis_error_mm"):
        c = summary["comparison"][name]
        mc, an = c["slope_monte_carlo"]["sensor.roll_deg"], c["jacobian_analytic"]["sensor.roll_deg"]
        assert np.sign(mc) == np.sign(an) and abs(mc - an) <= 0.2 * abs(an), (name, mc, an)
    # hinge row: a roll ρ turns the hinge, 2588 px from the sensor centre, by ≈ −2588·ρ [px/rad]
    assert summary["comparison"]["err.hinge_v_px"]["jacobian_analytic"]["sensor.roll_deg"] == pytest.approx(
        -(3196 - 607.5) * math.pi / 180, rel=0.05)
    assert (tmp_path / "o" / "report.md").is_file() and (tmp_path / "o" / "tornado.png").is_file()


@pytest.mark.render
@pytest.mark.slow
def test_the_dominant_tolerance_is_ranked_first(tmp_path):
    """Roll ±0.05° against the laser power ±0.5 mW (no geometric effect): Morris puts roll first."""
    from sim.study import load_study_spec, run_study

    text = TOLERANCE.replace('draws = 6', 'draws = 6\nmethod = "morris"').replace(
        '"sensor.roll_deg" = 0.05', '"laser.power_mw" = 0.5\n"sensor.roll_deg" = 0.05')
    (tmp_path / "s.toml").write_text(text)
    res = run_study(load_study_spec(tmp_path / "s.toml", "tolerance"), tmp_path / "o")
    ranked = res.summary["sensitivity"]
    assert [e["key"] for e in ranked] == ["sensor.roll_deg", "laser.power_mw"]
    assert ranked[0]["mu_star"] > 5 * ranked[1]["mu_star"]
    assert res.summary["analytic"]["geometric_effect"] == {"laser.power_mw": False, "sensor.roll_deg": True}
    assert res.summary["ranking"][0].startswith("sensor.roll_deg")


SWEEP = """
[study]
seed = 4
[rig]
preset = "paper"
[sweep]
"sensor.roll_deg" = [0.0, 0.04, -0.04]
[artefacts]
kinds = ["ball-bar"]
binning = 4
frames = 5
part = "cylinder"
part_step_deg = 45.0
"""


def _numbers(out: Path) -> list:
    return [json.loads(p.read_text())["outputs"] for p in sorted(out.glob("draws/*/draw.json"))]


@pytest.mark.render
@pytest.mark.slow
def test_two_workers_and_a_killed_run_give_the_numbers_of_one(tmp_path):
    from sim.study import load_study_spec, run_study

    (tmp_path / "s.toml").write_text(SWEEP)
    spec = load_study_spec(tmp_path / "s.toml", "sweep")
    two = run_study(spec, tmp_path / "two", workers=2)
    assert two.complete and len(_numbers(tmp_path / "two")) == 3
    assert all(0 < n["part_rms_mm"] < 0.2 for n in _numbers(tmp_path / "two"))      # the user part, scored
    out = tmp_path / "killed"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    cmd = [sys.executable, "-m", "scheimpflug", "study", "sweep", str(tmp_path / "s.toml"), "--out", str(out),
           "--quiet"]
    proc = subprocess.Popen(cmd, env=env, start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 300
    try:
        while time.monotonic() < deadline and proc.poll() is None:
            if (out / "draws" / "000000" / "draw.json").exists() and list(out.glob("draws/.*.partial/*/frames/*")):
                break                                       # one draw done, the next one part-way
            time.sleep(0.05)
        assert proc.poll() is None, "the run ended before it could be killed"
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    assert not (out / "draws" / "000002" / "draw.json").exists()
    res = subprocess.run(cmd, env=env, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    assert _numbers(out) == _numbers(tmp_path / "two")  # exact: resume
    assert not list(out.rglob("*.partial")) and not list(out.rglob(".*.tmp*"))


def test_latin_hypercube_sweep_fills_every_stratum_once(tmp_path):
    from sim.study import plan_draws

    text = ('[study]\nseed = 5\nsampling = "lhs"\ndesigns = 5\n[rig]\npreset = "paper"\n[sweep]\n'
            '"laser.tan_phi" = { range = [0.1, 0.3] }\n"lens.f_number" = { range = [4.0, 11.0] }\n'
            '[artefacts]\nkinds = []\n')
    plans = plan_draws(_spec(tmp_path, text, "sweep"))
    assert len(plans) == 5
    for key, (lo, hi) in (("laser.tan_phi", (0.1, 0.3)), ("lens.f_number", (4.0, 11.0))):
        strata = sorted(int((p.values[key] - lo) / (hi - lo) * 5) for p in plans)
        assert strata == [0, 1, 2, 3, 4]
        assert all(p.rig[key.split(".")[0]][key.split(".")[1]] == p.values[key] for p in plans)
    with pytest.raises(StudyError, match="study.designs is required"):
        _spec(tmp_path, text.replace("designs = 5\n", ""), "sweep")


_EXAMPLES = sorted((ROOT / "studies" / "examples").glob("*.toml"))


def test_every_example_spec_is_checked():
    # each example is parsed below by its own loader: a new kind of spec needs its test
    assert _EXAMPLES and all(p.stem.split("-")[0].split("_")[0] in ("sweep", "tolerance", "identify")
                             for p in _EXAMPLES)


@pytest.mark.parametrize("path", [p for p in _EXAMPLES if not p.stem.startswith("identify")], ids=lambda p: p.stem)
def test_example_study_specs_parse_and_plan(path):
    from sim.study import load_study_spec, plan_draws

    kind = "sweep" if path.stem.startswith("sweep") else "tolerance"
    plans = plan_draws(load_study_spec(path, kind))
    assert plans and all(p.artefacts.material == "metal" for p in plans)


@pytest.mark.parametrize("path", [p for p in _EXAMPLES if p.stem.startswith("identify")], ids=lambda p: p.stem)
def test_example_identify_specs_parse_and_plan(path):
    from sim.identify.spec import load_identify_spec, plan_design

    spec = load_identify_spec(path)
    plans = plan_design(spec)
    assert spec.parameters and spec.fitted and spec.held_out
    assert len(plans) == spec.runs and [p.index for p in plans] == list(range(spec.runs))
    for p in plans:     # every run's values inside its parameter's prior range
        assert all(q.lo <= p.values[q.key] <= q.hi for q in spec.parameters)


def test_a_study_folder_being_written_is_refused(tmp_path):
    from scheimpflug.io.folder import FolderLock
    from sim.study import load_study_spec, run_study

    (tmp_path / "s.toml").write_text('[rig]\npreset = "paper"\n[sweep]\n"laser.tan_phi" = [0.2]\n'
                                     '[artefacts]\nkinds = []\n')
    spec = load_study_spec(tmp_path / "s.toml", "sweep")
    (tmp_path / "out").mkdir()
    with FolderLock(tmp_path / "out"), pytest.raises(StudyError, match=f"pid {os.getpid()}"):
        run_study(spec, tmp_path / "out")
    assert run_study(spec, tmp_path / "out").complete            # the lock released: the study runs
