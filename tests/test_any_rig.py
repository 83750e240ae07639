"""The closed loop on rigs nobody tuned for (issue 16).

Twelve seeded random rigs (``tests/rig_draws.py``: f 12–100 mm, d 50–400 mm,
tan φ −0.3 … 0.5, pitch 2–10 µm, sensors 640 × 480 … 5000 × 4000, binned so
the file stays short) are rendered with the rig-aware defaults only — no stage
key, no scenario option — then calibrated, their axis located with the
blocker, and a cylinder (the paper's, scaled to the rig's rotary plan, its
knurl left out) scanned at 30° steps and reconstructed.  Tolerances (the
issue's): u_h and v_h within 0.5 px, F² and C within 0.05 %, d0 within
0.1 × the distance resolution at the centre column, the scan's RMS distance
to the mesh within 0.5 × the distance resolution at the axis.  The truth
comes from the rig's closed forms (``scheimpflug.model.hinge``), not from
the pipeline.  Rig 0 sets ``d0_mm = 0`` (the hinge at stage zero) to prove
that works too.

Also the issue's own rig (f = 35 mm, d = 120 mm, tan φ = 0.3, 3.45 µm,
2048 × 2448, hinge (4100, 1300)) end to end through the command line with no
stage option, and the design warnings for stage settings out of view.
"""

import json
import math
import warnings

import numpy as np
import pytest
from rig_draws import binning_for, draw_rigs

from scheimpflug.app.cli import main
from scheimpflug.model.binning import binned_rig
from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.plan import calibration_plan, rotary_plan, stage_warnings
from scheimpflug.model.rig import rig_from_dict

pytestmark = [pytest.mark.render, pytest.mark.slow]

SEED, N_RIGS = 2026, 12
RIG_TABLES = draw_rigs(SEED, N_RIGS)
RIG_TABLES[0] = {**RIG_TABLES[0], "stage": {"d0_mm": 0.0}}

ISSUE_RIG = """[lens]
focal_length_mm = 35.0
[laser]
scheimpflug_distance_mm = 120.0
tan_phi = 0.3
[sensor]
pixel_pitch_um = 3.45
columns = 2048
rows = 2448
hinge_column = 4100.0
axis_row = 1300.0
"""


def _rig(i):
    rig = rig_from_dict(RIG_TABLES[i])
    return binned_rig(rig, binning_for(rig.sensor.columns, rig.sensor.rows))


def _resolution_mm(g, u_px) -> float:
    return float(g.distance_resolution(u_px))


@pytest.fixture(scope="module")
def loops(tmp_path_factory):
    """Render and run the pipeline once per rig, on demand (cached)."""
    cache = {}

    def run(i):
        if i not in cache:
            cache[i] = _closed_loop(_rig(i), tmp_path_factory.mktemp(f"rig{i}"))
        return cache[i]

    return run


def _scaled_cylinder(path, rig):
    """The paper's cylinder shape (height 1.08 × diameter), 80 % of the rig's reference part, smooth."""
    R = 0.8 * rotary_plan(rig).part_radius_mm
    path.write_text(f'[[parts]]\nname = "cylinder"\npreset = "cylinder"\n[parts.params]\n'
                    f'diameter_mm = {2 * R!r}\nheight_mm = {2.16 * R!r}\nband_height_mm = 0.0\n')
    return str(path)


def _closed_loop(rig, root):
    from scheimpflug.axis import locate_axis
    from scheimpflug.calibration import calibrate_folder
    from scheimpflug.io.frames import open_frame_folder
    from scheimpflug.io.ply import read_mesh
    from scheimpflug.reconstruct import extract_folder, reconstruct_profiles
    from scheimpflug.scoring import PointToMesh
    from sim.writer import render_folder

    said = []
    opts = dict(seed=3, truth_pixels_every=0, warn=said.append)
    render_folder(rig, "calibration", root / "cal", **opts)
    render_folder(rig, "blocker", root / "blk", **opts)
    render_folder(rig, "rotary", root / "cyl", part=_scaled_cylinder(root / "cyl.toml", rig), step_deg=30.0,
                  **opts)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cal = calibrate_folder(root / "cal")
    axis_mm = locate_axis(root / "blk", cal.best).axis_mm
    ff = open_frame_folder(root / "cyl")
    rows, us, _, _ = extract_folder(ff, "cog", drop_isolated=True)
    cloud = reconstruct_profiles(rows, us, [r.angle_deg for r in ff.frames], cal.best, axis_mm)
    v, f, _ = read_mesh(root / "cyl" / "truth" / "mesh.ply")
    d = PointToMesh(v, f).query(cloud.xyz_mm).distance_mm
    return {"cal": cal, "axis_mm": axis_mm, "rms_mm": math.sqrt(float(np.mean(d ** 2))), "n_points": len(d),
            "warnings": said}


@pytest.mark.parametrize("i", range(N_RIGS))
def test_plan_of_a_random_rig(i):
    """The defaults put both plate edges in view in all 27 frames and the axis in view; no warning."""
    rig = _rig(i)
    plan = calibration_plan(rig)
    assert plan.steps == 27 and plan.both_edges_frames == 27 and plan.note == ""
    assert stage_warnings(rig) == []
    g = hinge_geometry(rig)
    D = plan.positions_mm() - rig.stage.d0_mm
    u = g.column_from_distance(D)
    assert np.all((u > 0) & (u < rig.sensor.columns - 1))
    for z in (plan.table_z_mm, plan.table_z_mm + plan.plate_height_mm):  # plate edges: rows inside the sensor
        _, v = g.pixel_from_sheet(D, np.full_like(D, z))
        assert np.all((v > 0) & (v < rig.sensor.rows - 1)), (z, v.min(), v.max())
    assert rotary_plan(rig).in_view and rotary_plan(rig).part_radius_mm > 0


@pytest.mark.parametrize("i", range(N_RIGS))
def test_calibration_of_a_random_rig(i, loops):
    rig = _rig(i)
    g = hinge_geometry(rig)
    res = loops(i)["cal"]
    cal = res.best
    assert not res.skipped and cal.n_frames == 27
    tol_d0 = 0.1 * _resolution_mm(g, rig.sensor.columns // 2)
    assert abs(cal.hinge_u_px - g.hinge_column) <= 0.5
    assert abs(cal.hinge_v_px - g.axis_row) <= 0.5
    assert abs(cal.F2_px_mm / g.F2_px_mm - 1) <= 5e-4
    assert abs(cal.C_mm / g.C_mm - 1) <= 5e-4
    assert abs(cal.d0_mm - rig.stage.d0_mm) <= tol_d0
    # the calibration states its own accuracy: every standard error exists
    assert all(math.isfinite(x) for x in (cal.hinge_u_sigma_px, cal.hinge_v_sigma_px, cal.F2_stderr_px_mm,
                                          cal.d0_sigma_mm, cal.C_stderr_mm))


@pytest.mark.parametrize("i", range(N_RIGS))
def test_rotary_scan_of_a_random_rig(i, loops):
    rig = _rig(i)
    g = hinge_geometry(rig)
    out = loops(i)
    res_axis = _resolution_mm(g, g.column_from_distance(rig.stage.axis_mm - rig.stage.d0_mm))
    assert out["n_points"] > 12 * 20
    assert abs(out["axis_mm"] - rig.stage.axis_mm) <= res_axis
    assert out["rms_mm"] <= 0.5 * res_axis


# ------------------------------------------------------------------ the issue's rig, command line only


def test_issue_rig_end_to_end_through_the_cli(tmp_path, capsys):
    rig_file = tmp_path / "MY.toml"
    rig_file.write_text(ISSUE_RIG)
    common = ["--rig", str(rig_file), "--binning", "4", "--truth-pixels", "none", "--quiet"]
    assert main(["render", "calibration", "--out", str(tmp_path / "cal"), *common]) == 0
    assert main(["calibrate", str(tmp_path / "cal"), "--out", str(tmp_path / "cal.json"), "--json", "--quiet"]) == 0
    cap = capsys.readouterr()
    cal = json.loads(cap.out)
    assert "warning" not in cap.err and cal["warnings"] == [] and cal["skipped"] == [] and cal["one_edge"] == []
    rig = binned_rig(rig_from_dict(_toml(ISSUE_RIG)), 4)  # what the command line renders
    g = hinge_geometry(rig)
    assert abs(cal["hinge_px"][0] - g.hinge_column) <= 0.5 and abs(cal["hinge_px"][1] - g.axis_row) <= 0.5
    assert abs(cal["F2_px_mm"] / g.F2_px_mm - 1) <= 5e-4 and abs(cal["C_mm"] / g.C_mm - 1) <= 5e-4
    assert abs(cal["d0_mm"] - rig.stage.d0_mm) <= 0.1 * _resolution_mm(g, rig.sensor.columns // 2)
    for key in ("hinge_u_sigma_px", "hinge_v_sigma_px", "F2_stderr_px_mm", "d0_sigma_mm", "C_stderr_mm"):
        assert cal[key] is not None and cal[key] > 0
    assert main(["render", "blocker", "--out", str(tmp_path / "blk"), *common]) == 0
    assert main(["render", "rotary", "--part", "cylinder", "--step-deg", "30", "--out", str(tmp_path / "cyl"),
                 *common]) == 0
    assert main(["axis", str(tmp_path / "blk"), "--calibration", str(tmp_path / "cal.json"), "--json"]) == 0
    axis_mm = json.loads(capsys.readouterr().out)["axis_mm"]
    res_axis = _resolution_mm(g, g.column_from_distance(rig.stage.axis_mm - rig.stage.d0_mm))
    assert abs(axis_mm - rig.stage.axis_mm) <= res_axis
    cloud = tmp_path / "cyl.ply"
    assert main(["reconstruct", str(tmp_path / "cyl"), "--calibration", str(tmp_path / "cal.json"),
                 "--axis-from", str(tmp_path / "blk"), "--drop-isolated", "--out", str(cloud), "--quiet"]) == 0
    capsys.readouterr()
    assert main(["evaluate", str(cloud), "--mesh", str(tmp_path / "cyl" / "truth" / "mesh.ply"), "--json"]) == 0
    ev = json.loads(capsys.readouterr().out)
    assert ev["n_points"] > 12 * 50 and ev["rms_mm"] <= 0.5 * res_axis


def _toml(text):
    import tomllib

    return tomllib.loads(text)


def test_design_warns_when_the_rigs_own_stage_settings_hide_axis_and_plate(tmp_path, capsys):
    """The issue's rig with the paper's stage settings: axis at column 2213.6 of 2048, plate cut."""
    rig_file = tmp_path / "MY.toml"
    rig_file.write_text(ISSUE_RIG + "[stage]\nd0_mm = -466.0\naxis_mm = 179.45\ncalibration_table_z_mm = -54.0\n"
                                    "calibration_plate_height_mm = 89.0\nrotary_table_z_mm = -70.0\n")
    assert main(["design", "--rig", str(rig_file), "--json"]) == 0
    cap = capsys.readouterr()
    rep = json.loads(cap.out)
    assert rep["axis_column_px"] == pytest.approx(2213.6, abs=0.1)
    axis_w, plate_w = rep["warnings"]
    assert "axis_mm = 179.45" in axis_w and "column 2213.6" in axis_w and "(-168.74, 125.92)" in axis_w
    assert "calibration_table_z_mm = -54" in plate_w and "[-62.67, -17.80]" in plate_w
    assert cap.err.count("warning") == 2
    assert not rep["rotary_plan"]["in_view"] and rep["calibration_plan"]["both_edges_frames"] < 27
    # without the stage table every key is derived and nothing is out of view
    rig_file.write_text(ISSUE_RIG)
    assert main(["design", "--rig", str(rig_file), "--json"]) == 0
    cap = capsys.readouterr()
    rep = json.loads(cap.out)
    assert rep["warnings"] == [] and "warning" not in cap.err
    assert rep["rotary_plan"]["in_view"] and rep["calibration_plan"]["both_edges_frames"] == 27
    assert {"stage.d0_mm", "stage.axis_mm", "sensor.exposure_ms"} <= set(rep["derived"])
