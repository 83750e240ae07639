"""Rig-aware defaults and the stage plan (scheimpflug.model.plan), against closed forms.

No rendering: the plan's promises (both plate edges inside the rows at every
planned frame, the reference cylinder inside the sensor at every angle) are
checked by mapping the plate's and the part's extreme points through paper
Eqs. 11–12 (``HingeGeometry.pixel_from_sheet``), on the issue's rig and on
fifty seeded random rigs.
"""

import json
import math

import numpy as np
import pytest
from rig_draws import binning_for, draw_rigs

from scheimpflug.app.cli import main
from scheimpflug.model.binning import binned_rig
from scheimpflug.model.camera import project_points
from scheimpflug.model.design import design_report
from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.plan import (
    EDGE_MARGIN_ROWS,
    EXPOSURE_FULL_WELL_FRACTION,
    PART_MARGIN_PX,
    calibration_plan,
    lambertian_peak_electrons_per_ms,
    rotary_plan,
    sheet_half_width_mm,
    stage_warnings,
    stripe_sigma_px,
)
from scheimpflug.model.rig import DERIVED_KEYS, load_preset, load_rig, rig_from_dict, rig_to_toml

ISSUE = {"lens": {"focal_length_mm": 35.0}, "laser": {"scheimpflug_distance_mm": 120.0, "tan_phi": 0.3},
         "sensor": {"pixel_pitch_um": 3.45, "columns": 2048, "rows": 2448, "hinge_column": 4100.0,
                    "axis_row": 1300.0}}


def _check_plan(rig):
    """Every planned frame shows both plate edges inside the row margins; the part fits at every angle."""
    g, s = hinge_geometry(rig), rig.sensor
    plan = calibration_plan(rig)
    assert plan.both_edges_frames == plan.steps == 27, plan.note
    D = plan.positions_mm() - rig.stage.d0_mm
    u = g.column_from_distance(D)
    assert np.all((u >= 0) & (u <= s.columns - 1))
    margin = min(EDGE_MARGIN_ROWS, s.rows / 6) - 1e-6
    for z in (plan.table_z_mm, plan.table_z_mm + plan.plate_height_mm):
        _, v = g.pixel_from_sheet(D, np.full_like(D, z))
        assert np.all((v >= margin - 0.5) & (v <= s.rows - 0.5 - margin)), (z, v.min(), v.max())
    rp = rotary_plan(rig)
    assert rp.in_view and rp.part_radius_mm > 0
    R, Da, z = rp.part_radius_mm, rp.axis_distance_mm, rp.table_z_mm
    Dc, hc = np.meshgrid([Da - R, Da + R], [z, z + 2 * R])
    uc, vc = g.pixel_from_sheet(Dc, hc)
    m = min(PART_MARGIN_PX, s.columns / 6, s.rows / 6) - 1e-6
    assert np.all((uc >= m) & (uc <= s.columns - 1 - m) & (vc >= m - 0.5) & (vc <= s.rows - 0.5 - m))


def test_paper_preset_derives_nothing():
    rig = load_preset("paper")
    assert rig.derived == ()
    assert (rig.stage.d0_mm, rig.stage.axis_mm, rig.stage.calibration_table_z_mm, rig.stage.rotary_table_z_mm,
            rig.stage.calibration_plate_height_mm) == (-466.0, 179.45, -54.0, -70.0, 89.0)
    assert (rig.laser.waist_distance_mm, rig.sensor.exposure_ms) == (640.0, 0.5)
    assert stage_warnings(rig) == []


def test_rule_on_the_issues_rig():
    rig = rig_from_dict(ISSUE)
    assert rig.derived == DERIVED_KEYS
    g = hinge_geometry(rig)
    assert rig.stage.d0_mm == -math.floor(float(g.distance_from_column(0.0)))  # stage zero at the near end
    _check_plan(rig)
    # the axis: the largest cylinder as tall as it is wide; the paper's Ø100 × 108 mm cylinder fits too
    rp = rotary_plan(rig)
    assert rp.part_height_mm == pytest.approx(2 * rp.part_radius_mm) and rp.part_radius_mm > 54.0
    assert 0 < float(g.column_from_distance(rp.axis_distance_mm)) < 2047
    # the laser's waist sits at the rotary axis
    assert sheet_half_width_mm(rig, rp.axis_distance_mm) == pytest.approx(rig.laser.waist_um * 1e-3, rel=1e-3)


@pytest.mark.parametrize("i", range(50))
def test_rule_on_random_rigs(i):
    """Fifty rigs of other seeds, full and binned: the plan's promises hold by closed form."""
    tables = draw_rigs(777, 50)[i]
    rig = rig_from_dict(tables)
    _check_plan(rig)
    _check_plan(binned_rig(rig, binning_for(rig.sensor.columns, rig.sensor.rows)))


def test_rig_file_records_the_derived_values(tmp_path):
    rig = rig_from_dict(ISSUE)
    text = rig_to_toml(rig)
    assert text.count("# derived") == len(DERIVED_KEYS)
    path = tmp_path / "r.toml"
    path.write_text(text)
    again = load_rig(path)
    assert again == rig and again.derived == ()  # written values are the rig's own now


def test_replace_derives_again_unless_given():
    rig = rig_from_dict(ISSUE)
    longer = rig.replace(lens={"focal_length_mm": 50.0})
    assert longer.derived == rig.derived and longer.stage.d0_mm != rig.stage.d0_mm
    _check_plan(longer)
    moved = rig.replace(stage={"axis_mm": rig.stage.axis_mm - 20.0})
    assert "stage.axis_mm" not in moved.derived and moved.stage.axis_mm == rig.stage.axis_mm - 20.0
    assert moved.stage.rotary_table_z_mm != rig.stage.rotary_table_z_mm  # the table follows the given axis
    kept = rig.replace(rederive=False, lens={"focal_length_mm": 50.0})
    assert kept.stage == rig.stage and kept.derived == rig.derived


def test_d0_zero_works():
    rig = rig_from_dict({**ISSUE, "stage": {"d0_mm": 0.0}})
    assert rig.stage.d0_mm == 0.0 and "stage.d0_mm" not in rig.derived
    _check_plan(rig)
    rep = design_report(rig)
    json.dumps(rep, allow_nan=False)
    assert rep["stage_zero_column_px"] is None and rep["focal_length_check_mm"] is None
    plan = calibration_plan(rig)
    assert plan.start_mm >= float(hinge_geometry(rig).distance_from_column(0.0))  # s = D when d0 = 0


def test_exposure_rule():
    """Paper rig: the closed form puts a white Lambertian stripe on the axis at 1/6 of the full well
    at 0.49 ms, next to the paper preset's 0.5 ms; a binned read-out derives its own exposure."""
    paper = load_preset("paper")
    axis_D = paper.stage.axis_mm - paper.stage.d0_mm
    per_ms = lambertian_peak_electrons_per_ms(paper, axis_D)
    assert EXPOSURE_FULL_WELL_FRACTION * paper.sensor.full_well_e / per_ms == pytest.approx(0.5, rel=0.05)
    rig = rig_from_dict(ISSUE)
    binned = binned_rig(rig, 4)
    assert "sensor.exposure_ms" in binned.derived and binned.sensor.exposure_ms < rig.sensor.exposure_ms / 4
    dark = rig_from_dict({**ISSUE, "laser": {**ISSUE["laser"], "power_mw": 0.0}})
    assert dark.sensor.exposure_ms == 1.0


@pytest.mark.parametrize("D", [300.0, 450.0, 590.0])
def test_stripe_width_matches_the_camera_model(D):
    """σ across the columns = (w/2)·|du/dδ|: the closed form against model.camera's projection."""
    rig = rig_from_dict(ISSUE)
    g = hinge_geometry(rig)
    p = g.rig_from_sheet(D, 0.0)
    e = 1e-3
    uv = project_points(rig, np.stack([p - e * g.sheet_normal, p + e * g.sheet_normal])).uv_px
    expected = abs(uv[1, 0] - uv[0, 0]) / (2 * e) * 0.5 * sheet_half_width_mm(rig, D)
    assert stripe_sigma_px(rig, D) == pytest.approx(expected, rel=1e-6)


def test_warnings_name_the_key_and_the_range():
    low = rig_from_dict({**ISSUE, "stage": {"rotary_table_z_mm": -500.0}})
    (w,) = stage_warnings(low)
    assert w.startswith("[stage] rotary_table_z_mm = -500") and "use a value in [" in w
    tall = rig_from_dict({**ISSUE, "stage": {"calibration_plate_height_mm": 400.0}})
    (w,) = stage_warnings(tall)
    assert "taller than the view" in w and "calibration_plate_height_mm" in w


def test_design_table_prints_the_plans(tmp_path, capsys):
    path = tmp_path / "MY.toml"
    path.write_text("[lens]\nfocal_length_mm = 35.0\n[laser]\nscheimpflug_distance_mm = 120.0\ntan_phi = 0.3\n"
                    "[sensor]\npixel_pitch_um = 3.45\ncolumns = 2048\nrows = 2448\nhinge_column = 4100.0\n"
                    "axis_row = 1300.0\n")
    assert main(["design", "--rig", str(path)]) == 0
    out = capsys.readouterr().out
    assert "calibration plan  plate 67 mm" in out and "both plate edges in view in 27 of 27" in out
    assert "rotary plan       axis at s = 240.4 mm" in out and "(derived)" in out
