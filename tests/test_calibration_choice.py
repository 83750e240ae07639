"""Which calibration for my rig (issue 24 item 5): the three calibrations of one rig against the rendered truth.

A small plan (4 × 4 binned sensor, 9 plate frames, 12 board poses, coarse scans) keeps it
fast; the full-resolution figures are benchmarks/RESULTS.md's.  Every reference is the
twin's geometry (its camera, sheet and axis, the exact stripe points), not the calibrations'.
"""

import math

import pytest

from scheimpflug.model.rig import load_preset
from sim.calibration_choice import CHOICE_FIGURES, ChoicePlan, compare_calibrations


@pytest.fixture(scope="module")
def choice(tmp_path_factory):
    plan = ChoicePlan(binning=4, plate_steps=9, plate_step_mm=26.0, plate_start_mm=31.0, plate_subsets=(5,),
                      poses=12, pose_subsets=(), table_step_deg=45.0, cylinder_step_deg=20.0, pile_step_deg=20.0,
                      camera_spp=4, scale=1.0, acceptance=True)
    return compare_calibrations(load_preset("paper"), plan, tmp_path_factory.mktemp("choice"))


@pytest.mark.render
def test_every_calibration_has_every_figure(choice, variant):
    assert set(choice["methods"]) == {"paper", "general", "paper-5", "target", "target+blocker", "target-bow"}
    for name, m in choice["methods"].items():
        assert all(math.isfinite(m[k]) for k in CHOICE_FIGURES), name


@pytest.mark.render
def test_the_stage_calibrations_hold_the_truth(choice, variant):
    for name in ("paper", "general"):
        m = choice["methods"][name]
        assert m["sheet_rms_mm"] < 0.005 and m["axis_offset_mm"] < 0.05, name     # binned pixels: 23 µm
        assert abs(m["cylinder_diameter_error_mm"]) < 0.05, name
    assert choice["methods"]["paper"]["plane_normal_deg"] < 0.05                  # the ideal rig's own form


# The bounds below hold in each of 16 noise draws of this plan (seeds 0-7, with the sensor noise's
# streams before and after issue 27's third round; benchmarks/RESULTS.md): the table poses' axis
# 0.07-1.22 mm off (median 0.28), the blocker's 0.02-0.15 mm (median 0.07) — nearer in 15 of the 16,
# so a pair of one draw may not show it —, the cylinder's diameter 0.08-2.39 against 0.03-0.23 mm
# off, the blocker's cylinder form 1.1-2.2 × the stage calibration's, the bowed print's sheet
# 5.0-45 × the flat one's RMS, |SD| 0.54-1.43 × the axis offset.
@pytest.mark.render
def test_the_pattern_calibration_and_what_weakens_it(choice, variant):
    t, tb, bow = (choice["methods"][k] for k in ("target", "target+blocker", "target-bow"))
    assert t["sheet_rms_mm"] < 0.15 and t["plane_normal_deg"] < 1.0 and t["axis_offset_mm"] < 2.0
    # the table poses' axis is its weak link: the blocker's, with the same camera and plane, stays near
    assert tb["axis_offset_mm"] < 0.25 and abs(tb["cylinder_diameter_error_mm"]) < 0.3
    # with the axis's direction in the sheet from the blocker's face the cylinder stays a cylinder: its form
    # within 3 × the stage calibration's (an axis tilted in the sheet would scan a cone)
    assert tb["cylinder_form_rms_mm"] < 3 * choice["methods"]["paper"]["cylinder_form_rms_mm"]
    # a print bowed by 0.5 mm that the calibration takes for flat bends the sheet it finds
    assert bow["sheet_rms_mm"] > 2 * t["sheet_rms_mm"]


@pytest.mark.render
def test_vdi_figures_of_every_calibration_from_one_rendering(choice, variant):
    for name, m in choice["methods"].items():
        v = m["vdi"]
        assert not v["failed"] and all(math.isfinite(v[k]) for k in ("PF_mm", "PS_mm", "SD_mm", "F_mm")), name
    paper = choice["methods"]["paper"]["vdi"]
    assert abs(paper["PS_mm"]) < 0.05 and abs(paper["SD_mm"]) < 0.05          # the ideal rig, binned
    # the pattern's sizes carry its axis error δ and its sheet's ε: |SD| < 2 (δ + ε_max); where δ dominates
    # (δ > 3 ε_max: the table poses' axis) |SD| is at least 0.4 δ.  Issue 34's calibration (the board found
    # in more poses, the laser line's points on the board only) put the blocker's axis 0.003 mm off with the
    # sheet at 0.07 mm max and |SD| 0.019 mm: there ε dominates, and δ alone says nothing of SD.
    for name in ("target", "target+blocker"):
        m = choice["methods"][name]
        axis, sheet = m["axis_offset_mm"], m["sheet_max_mm"]
        assert abs(m["vdi"]["SD_mm"]) < 2 * (axis + sheet), name
        if axis > 3 * sheet:
            assert abs(m["vdi"]["SD_mm"]) > 0.4 * axis, name
