"""Hostile inputs of the instrument pipeline (issue 25, the pipeline's inputs): frames listed twice,
values beyond the ADC range, units and ranges the manifest can check, a ghost stripe and
upside-down frames, the OpenCV export with a distorting lens, tracebacks and unclear messages.

Synthetic frames from the closed forms (``synth_frames``) on the 8 × 8 binned paper geometry of
``test_hostile_calibration`` (152 × 242 px); nothing here renders.
"""

import json
import math
import shutil
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh
from synth_frames import Camera, PlateScene, calibration_folder, plate_frame, rig_dict, write_folder
from test_hostile_calibration import GEO, STAGES
from test_reconstruct_cli import _cylinder_scan

from scheimpflug.app.cli import main
from scheimpflug.calibration import Calibration, calibrate_folder, calibrate_measurements
from scheimpflug.errors import CalibrationError, FrameError
from scheimpflug.io.frames import open_frame_folder
from scheimpflug.io.importer import import_frames, positions_from_csv, positions_from_names
from scheimpflug.stripe import extract_stripes

PITCH_8_UM = 8 * 5.86        # the binned geometry's pixel pitch: a rig that states it is consistent with GEO


@pytest.fixture(autouse=True)
def _quiet():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


def _fails(args, capsys, *needles):
    """The command fails with one error line (warnings before it are fine) and no traceback."""
    capsys.readouterr()
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    lines = [line for line in err.splitlines() if not line.startswith(("warning", "note"))]
    assert len(lines) == 1 and "Traceback" not in err, err
    for n in needles:
        assert n in err, err
    return err


def _manifest(path):
    return json.loads((path / "manifest.json").read_text())


def _edit(path, edit):
    m = _manifest(path)
    edit(m)
    (path / "manifest.json").write_text(json.dumps(m))
    return path


def _plates(path, transform=None, stages=STAGES, rig=None, seed=3, scene=PlateScene(), params=None):
    """A calibration folder of GEO plate frames, each passed through ``transform(frame)``."""
    rng = np.random.default_rng(seed)
    frames = [plate_frame(GEO, s, scene, Camera(), rng)[0] for s in stages]
    if transform is not None:
        frames = [transform(f) for f in frames]
    return write_folder(path, frames, [{"stage_mm": float(s)} for s in stages],
                        rig=rig if rig is not None else rig_dict(GEO),
                        scenario_params=params if params is not None else {"plate_height_mm": 89.0})


def _consistent_rig():
    """rig_dict(GEO) with the binned pixel pitch GEO's F² implies (the synth helper keeps 5.86 µm)."""
    rig = rig_dict(GEO)
    rig["sensor"]["pixel_pitch_um"] = PITCH_8_UM
    return rig


@pytest.fixture(scope="module")
def plate(tmp_path_factory):
    root = tmp_path_factory.mktemp("plate")
    path, _ = calibration_folder(root / "cal", GEO, stages=STAGES, seed=3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        calibrate_folder(path).best.save(root / "cal.json")
    return path, root / "cal.json"


# ------------------------------------------------------------------ item 1: a frame listed twice


def test_calibrate_refuses_a_frame_listed_twice(plate, tmp_path, capsys):
    """Two entries with one file were calibrated silently (the standard errors shrank)."""
    src, _ = plate
    twice = _edit(shutil.copytree(src, tmp_path / "twice"),
                  lambda m: m["frames"].append(dict(m["frames"][4], stage_mm=m["frames"][4]["stage_mm"])))
    _fails(["calibrate", str(twice), "--quiet"], capsys, "frames[4] and frames[10] both list",
           "frames/00004.png")
    with pytest.raises(FrameError, match="listed twice"):
        calibrate_folder(twice)


def test_calibrate_refuses_one_file_under_two_names(plate, tmp_path, capsys):
    src, _ = plate
    copy = shutil.copytree(src, tmp_path / "copy")
    shutil.copy(copy / "frames" / "00004.png", copy / "frames" / "extra.png")
    _edit(copy, lambda m: m["frames"].append({"file": "frames/extra.png", "stage_mm": 250.0}))
    _fails(["calibrate", str(copy), "--quiet"], capsys, "frames/00004.png", "frames/extra.png",
           "same file content")


def test_axis_refuses_a_blocker_frame_listed_twice(plate, tmp_path, capsys):
    _, cal = plate
    rng = np.random.default_rng(7)
    face = [plate_frame(GEO, 150.0, PlateScene(bottom_mm=-70.0, height_mm=140.0), Camera(), rng)[0]
            for _ in range(2)]
    blk = write_folder(tmp_path / "blk", face, [{"angle_deg": 0.0}] * 2, scenario="blocker", rig=rig_dict(GEO),
                       scenario_params={"blocker_thickness_mm": 2.0})
    assert main(["axis", str(blk), "--calibration", str(cal)]) == 0
    _edit(blk, lambda m: m["frames"].append(dict(m["frames"][1])))
    _fails(["axis", str(blk), "--calibration", str(cal)], capsys, "frames[1] and frames[2] both list")


def test_reconstruct_refuses_a_frame_under_two_names(tmp_path, rng, capsys):
    from test_reconstruct_cli import AXIS, COLS, D0, F2, ROWS, U_H, V_H, C

    Calibration(hinge_u_px=U_H, hinge_v_px=V_H, F2_px_mm=F2, F2_sigma_px_mm=0.0, d0_mm=D0, C_mm=C,
                C_sigma_mm=0.0, endpoint_fit_r2=(1.0, 1.0), method="paper", columns=COLS,
                rows=ROWS).save(tmp_path / "cal.json")
    scan, _ = _cylinder_scan(tmp_path, rng, n_frames=4)
    shutil.copy(scan / "frames" / "00001.png", scan / "frames" / "dup.png")
    _edit(scan, lambda m: m["frames"].append({"file": "frames/dup.png", "angle_deg": 300.0}))
    _fails(["reconstruct", str(scan), "--calibration", str(tmp_path / "cal.json"), "--axis-mm", str(AXIS),
            "--out", str(tmp_path / "c.ply"), "--quiet"], capsys, "frames/00001.png", "frames/dup.png")
    assert not (tmp_path / "c.ply").exists()


def _sources(tmp_path, n=3, value=lambda k: 100 + k, dtype=np.uint16):
    paths = []
    for k in range(n):
        p = tmp_path / f"p_{10 * k}.png"
        assert cv2.imwrite(str(p), np.full((20, 30), value(k), dtype))
        paths.append(p)
    return paths


def test_import_refuses_a_file_twice_and_one_image_under_two_names(tmp_path, capsys):
    files = _sources(tmp_path)
    _fails(["import", *map(str, files), str(files[1]), "--positions-from-names", "p_{stage_mm}.png",
            "--out", str(tmp_path / "o")], capsys, "p_10.png", "given twice")
    shutil.copy(files[1], tmp_path / "p_10.0.png")           # a name that parses to the same position
    _fails(["import", *map(str, files), str(tmp_path / "p_10.0.png"), "--positions-from-names",
            "p_{stage_mm}.png", "--out", str(tmp_path / "o")], capsys, "p_10.png", "p_10.0.png",
           "same image")
    assert not (tmp_path / "o").exists()


def test_import_warns_of_two_frames_at_one_position(tmp_path, capsys):
    files = _sources(tmp_path)
    other = tmp_path / "p_10.0.png"
    assert cv2.imwrite(str(other), np.full((20, 30), 7, np.uint16))
    assert main(["import", *map(str, files), str(other), "--positions-from-names", "p_{stage_mm}.png",
                 "--out", str(tmp_path / "o")]) == 0
    assert "same stage_mm = 10" in capsys.readouterr().err


def test_positions_csv_listing_a_file_twice_is_refused(tmp_path):
    """It kept the last row silently (for angles too)."""
    files = _sources(tmp_path)
    for key in ("stage_mm", "angle_deg"):
        (tmp_path / "pos.csv").write_text(f"file,{key}\np_0.png,0\np_10.png,1\np_20.png,2\np_10.png,5\n")
        with pytest.raises(FrameError, match=r"lists 'p_10.png' twice \(lines 3 and 5\)"):
            positions_from_csv(files, tmp_path / "pos.csv")


# ------------------------------------------------------------------ item 2: values beyond the ADC range


def _saturating_plates():
    """Three 12-bit GEO plate frames whose stripe clips at 4095 in most rows."""
    rng = np.random.default_rng(4)
    scene = PlateScene(total_e=400000.0)
    return [plate_frame(GEO, s, scene, Camera(), rng)[0] for s in (80.0, 140.0, 200.0)]


def _saturated_rows(frame, saturation_dn):
    return int(extract_stripes(frame, "cog", saturation_dn=saturation_dn).saturated.sum())


def test_msb_aligned_data_are_named_and_their_saturation_counted(tmp_path, capsys):
    """12-bit codes × 16 imported with --adc-bits 12: 0 saturated rows instead of most."""
    raw = _saturating_plates()
    expected = [_saturated_rows(f, 4095.0) for f in raw]
    assert min(expected) > 100
    src = tmp_path / "src"
    src.mkdir()
    for f, s in zip(raw, (80, 140, 200)):
        assert cv2.imwrite(str(src / f"plate_{s}.png"), (f << 4).astype(np.uint16))
    base = ["import", str(src), "--positions-from-names", "plate_{stage_mm}.png", "--adc-bits", "12"]
    err = _fails(base + ["--out", str(tmp_path / "o")], capsys, "plate_80.png", "above 4095",
                 "MSB-aligned", "--msb-aligned")
    assert "up to 65520" in err
    assert main(base + ["--msb-aligned", "--out", str(tmp_path / "o")]) == 0
    ff = open_frame_folder(tmp_path / "o")
    got = [_saturated_rows(ff.read(i), ff.saturation_dn(ff.read(i))) for i in range(len(ff))]
    assert got == expected and int(ff.read(0).max()) == 4095
    # a frame folder that holds MSB-aligned codes under adc_bits = 12: saturation at 4095 × 16
    shifted = write_folder(tmp_path / "msb", [(f << 4).astype(np.uint16) for f in raw],
                           [{"stage_mm": s} for s in (80.0, 140.0, 200.0)], rig=rig_dict(GEO))
    ff = open_frame_folder(shifted)
    assert ff.saturation_dn(ff.read(0)) == 4095.0 * 16
    assert [_saturated_rows(ff.read(i), ff.saturation_dn(ff.read(i))) for i in range(3)] == expected


def test_values_above_a_small_adc_depth_are_refused(tmp_path, capsys):
    """16-bit data up to 15 200 were accepted with --adc-bits 8."""
    files = _sources(tmp_path, value=lambda k: 15200 - k)
    _fails(["import", *map(str, files), "--positions-from-names", "p_{stage_mm}.png", "--adc-bits", "8",
            "--out", str(tmp_path / "o")], capsys, "p_0.png", "up to 15200", "above 255", "14-bit")
    folder = write_folder(tmp_path / "f", [np.full((242, 152), 15200 - k, np.uint16) for k in range(3)],
                          [{"stage_mm": 10.0 * k} for k in range(3)],
                          rig={"sensor": {"rows": 242, "columns": 152, "adc_bits": 8}})
    with pytest.raises(FrameError, match=r"00000.png.*values up to 15200, above 255"):
        open_frame_folder(folder).read(0)


# ------------------------------------------------------------------ item 3: units and ranges


@pytest.mark.parametrize("axis", ["1794.5", "5000", "-1000"])
def test_reconstruct_axis_outside_the_calibrated_range_is_refused(tmp_path, rng, capsys, axis):
    from test_reconstruct_cli import COLS, D0, F2, ROWS, U_H, V_H, C

    Calibration(hinge_u_px=U_H, hinge_v_px=V_H, F2_px_mm=F2, F2_sigma_px_mm=0.0, d0_mm=D0, C_mm=C,
                C_sigma_mm=0.0, endpoint_fit_r2=(1.0, 1.0), method="paper", columns=COLS,
                rows=ROWS).save(tmp_path / "cal.json")
    scan, _ = _cylinder_scan(tmp_path, rng, n_frames=3)
    _fails(["reconstruct", str(scan), "--calibration", str(tmp_path / "cal.json"), "--axis-mm", axis,
            "--out", str(tmp_path / "c.ply"), "--quiet"], capsys, "outside the depth range",
           "24.92 … 99.80 mm")


def _scan_of(path, geo_scale: int):
    """Blank-ish rotary frames of a sensor binned ``geo_scale`` × less than GEO (rig hinge scaled)."""
    rig = rig_dict(GEO)
    for key in ("rows", "columns", "hinge_column", "axis_row"):
        rig["sensor"][key] = rig["sensor"][key] * geo_scale
    rng = np.random.default_rng(1)
    shape = (GEO.rows * geo_scale, GEO.columns * geo_scale)
    frames = [rng.integers(10, 30, shape).astype(np.uint16) for _ in range(3)]
    return write_folder(path, frames, [{"angle_deg": 10.0 * k} for k in range(3)], scenario="rotary", rig=rig)


def test_a_calibration_of_another_binning_is_refused_also_without_its_size(plate, tmp_path, capsys):
    """A binning-4 calibration was accepted for a binning-2 scan (cylinder Ø 491.6 mm, RMS 219 mm)."""
    _, cal = plate
    d = json.loads(cal.read_text())
    assert d["stage_range_mm"] == [60.0, 240.0]
    for key in ("columns", "rows", "pixel_pitch_um", "stage_range_mm"):   # a file written before them
        d.pop(key)
    (tmp_path / "old.json").write_text(json.dumps(d))
    scan = _scan_of(tmp_path / "scan", 2)
    errs = [_fails(["reconstruct", str(scan), "--calibration", str(c), "--axis-mm", "150",
                    "--out", str(tmp_path / "c.ply"), "--quiet"], capsys, "binning")
            for c in (cal, tmp_path / "old.json")]
    assert "a calibration made at 2 × this binning" in errs[0]
    assert "0.5 × the frames' rig hinge_column 799" in errs[1]


@pytest.mark.parametrize("unit, factor", [("cm", 10.0), ("inches", 25.4)])
def test_stage_positions_in_other_units_are_refused(tmp_path, capsys, unit, factor):
    folder = _plates(tmp_path / unit, rig=_consistent_rig())
    assert main(["calibrate", str(folder), "--quiet"]) == 0
    _edit(folder, lambda m: [f.update(stage_mm=f["stage_mm"] / factor) for f in m["frames"]])
    _fails(["calibrate", str(folder), "--quiet"], capsys, f"look like {unit}, not mm", f"× {factor:g}")


def test_a_wrong_plate_height_is_named(tmp_path, capsys):
    folder = _plates(tmp_path / "h", rig=_consistent_rig(), params={"plate_height_mm": 60.0})
    capsys.readouterr()
    assert main(["calibrate", str(folder), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "is the plate height 60 mm right?" in err, err
    implied = float(err.split("the plate would be ")[1].split(" mm")[0])
    assert abs(implied - 89.0) < 0.2, err


def test_angles_in_radians_are_named(tmp_path, capsys):
    n = 12
    files = []
    for k in range(n):
        p = tmp_path / f"s_{2 * math.pi * k / n:.6f}.png"
        assert cv2.imwrite(str(p), np.full((20, 30), 100 + k, np.uint16))
        files.append(str(p))
    assert main(["import", *files, "--positions-from-names", "s_{angle_deg}.png", "--out",
                 str(tmp_path / "o")]) == 0
    assert "one turn in radians" in capsys.readouterr().err


@pytest.mark.parametrize("factor, unit", [(1000.0, "metres"), (25.4, "inches"), (10.0, "cm"), (1.0, None)])
def test_evaluate_names_a_gross_scale_mismatch(tmp_path, capsys, factor, unit):
    """A cloud in metres, inches or cm scored against a mesh in mm: RMS 61–1480 mm, no word."""
    trimesh.creation.icosphere(subdivisions=3, radius=50.0).export(tmp_path / "ball.ply")
    rng = np.random.default_rng(2)
    d = rng.normal(size=(2000, 3))
    xyz = 50.0 * d / np.linalg.norm(d, axis=1, keepdims=True) / factor
    (tmp_path / "c.ply").write_text("ply\nformat ascii 1.0\nelement vertex 2000\nproperty double x\n"
                                    "property double y\nproperty double z\nend_header\n"
                                    + "\n".join(" ".join(map(repr, p)) for p in xyz.tolist()) + "\n")
    capsys.readouterr()
    assert main(["evaluate", str(tmp_path / "c.ply"), "--mesh", str(tmp_path / "ball.ply"), "--json"]) == 0
    cap = capsys.readouterr()
    out = json.loads(cap.out)
    if unit is None:
        assert out["scale_warning"] is None and "warning" not in cap.err
    else:
        assert f"looks like it is in {unit}" in cap.err and out["scale_warning"], cap.err


# ------------------------------------------------------------------ item 4: ghost stripe, upside down


def _ghost(frame, shift=8, gain=0.9):
    """A second, 0.9 × bright copy of the stripe ``shift`` columns to the right (no wrap)."""
    g = frame.astype(np.float64) - 16.0
    copy = np.zeros_like(g)
    copy[:, shift:] = g[:, :-shift]
    return np.clip(frame + gain * copy, 0, 4095).astype(np.uint16)


def test_a_ghost_stripe_is_refused_naming_the_rows(tmp_path, capsys):
    """It moved u_h by 3.7 px (105 of its own σ) without a warning."""
    folder = _plates(tmp_path / "ghost", _ghost)
    err = _fails(["calibrate", str(folder), "--quiet"], capsys, "9 × two stripes",
                 "frames/00000.png: two stripes: ", "of its", "lit rows show a second peak of comparable height",
                 "also frames/00001.png, frames/00002.png, 6 more")
    rows = int(err.split("two stripes: ")[1].split(" of its")[0])
    assert rows > 100, err


def test_upside_down_frames_are_refused(tmp_path, capsys):
    """The cloud's z came out mirrored (RMS 10 mm) and every command passed."""
    folder = _plates(tmp_path / "flip", lambda f: f[::-1].copy())
    _fails(["calibrate", str(folder), "--quiet"], capsys, "upside down", "axis_row 96.375")
    assert main(["calibrate", str(_plates(tmp_path / "up")), "--quiet"]) == 0


# ------------------------------------------------------------------ item 5: the OpenCV export


def test_opencv_export_with_a_distorting_lens_is_metric(tmp_path):
    """undistortPoints ∩ laser_plane made the plate 0.1–1 % long; now the camera frame is the sheet's."""
    from scheimpflug.calibration import PlateMeasurement
    from scheimpflug.calibration.opencv import opencv_dict
    from scheimpflug.sheet_model import fit_sheet_models, ideal_camera

    paper = Calibration(hinge_u_px=GEO.hinge_u_px, hinge_v_px=GEO.hinge_v_px, F2_px_mm=GEO.F2_px_mm,
                        F2_sigma_px_mm=0.0, d0_mm=GEO.d0_mm, C_mm=GEO.C_mm, C_sigma_mm=0.0,
                        endpoint_fit_r2=(1.0, 1.0), method="paper", columns=GEO.columns, rows=GEO.rows)
    cam, g = ideal_camera(paper, 55.0, PITCH_8_UM)
    from dataclasses import replace

    truth = replace(cam, k1=-0.15)
    rng = np.random.default_rng(0)

    def pixel(s, h):
        w = g @ np.stack([s, h, np.ones_like(s)])
        return truth.pixel_from_normalized(w[0] / w[2], w[1] / w[2])

    ms, h_b = [], -54.0
    for s in STAGES:
        h = np.linspace(h_b + 2, h_b + 87, 120)
        u, v = pixel(np.full_like(h, s), h)
        u = u + rng.normal(0, 0.01, u.size)
        (ut, vt), (ub, vb) = (pixel(np.array([s]), np.array([hh])) for hh in (h_b + 89.0, h_b))
        ms.append(PlateMeasurement(stage_mm=float(s), u_mean_px=float(u.mean()), n_rows=u.size,
                                   line=(float(u.mean()), 0.0), top_px=(float(ut[0]), float(vt[0])),
                                   bottom_px=(float(ub[0]), float(vb[0])), rows=v, u=u))
    first = calibrate_measurements(ms, columns=GEO.columns, rows=GEO.rows)
    _, _, general, sel = fit_sheet_models(ms, first, focal_length_mm=55.0, pixel_pitch_um=PITCH_8_UM)
    assert sel.chosen == "general"
    d = opencv_dict(general, 55.0, PITCH_8_UM)
    sf = {k: np.asarray(v) for k, v in d["sheet_frame"].items() if k != "metric_error"}
    assert abs(np.linalg.norm(sf["height_axis"]) - 1) < 1e-9 and abs(sf["stage_axis"] @ sf["height_axis"]) < 1e-9
    # the plate's edges measured through OpenCV (default undistortPoints) and through the pipeline
    a, b, c, dd = d["laser_plane"]
    K, D = np.array(d["camera_matrix"]), np.array(d["dist_coeffs"])
    for m in ms:
        uv = np.array([m.top_px, m.bottom_px])
        xy = cv2.undistortPoints(uv.reshape(-1, 1, 2), K, D).reshape(-1, 2)
        ray = np.column_stack([xy, np.ones(2)])
        hit = ray * (-dd / (ray @ [a, b, c]))[:, None]
        s, h = general.stage_from_pixel(uv[:, 0], uv[:, 1])
        assert abs(np.linalg.norm(hit[0] - hit[1]) - math.hypot(s[0] - s[1], h[0] - h[1])) < 1e-4
        assert abs(h[0] - h[1] - 89.0) < 0.05


# ------------------------------------------------------------------ item 6: tracebacks


def test_positions_csv_with_an_empty_first_line_or_a_bom(tmp_path, capsys):
    """An empty first line was a traceback (exit 70); a UTF-8 BOM in the header was refused."""
    files = _sources(tmp_path)
    for name, text in (("blank.csv", "\nfile,stage_mm\np_0.png,0\np_10.png,1\np_20.png,2\n"),
                       ("bom.csv", "\ufefffile,stage_mm\np_0.png,0\np_10.png,1\np_20.png,2\n")):
        (tmp_path / name).write_text(text, encoding="utf-8")
        assert [f.value for f in positions_from_csv(files, tmp_path / name)] == [0.0, 1.0, 2.0]
    (tmp_path / "empty.csv").write_text("\n\n")
    _fails(["import", *map(str, files), "--positions", str(tmp_path / "empty.csv"), "--out",
            str(tmp_path / "o")], capsys, "needs a header with 'file'", "got nothing")


@pytest.mark.parametrize("value", ["0", "-3", "100000"])
def test_acceptance_binning_out_of_range_is_one_line(tmp_path, capsys, value):
    _fails(["acceptance", "--binning", value, "--out", str(tmp_path / "acc"), "--quick"], capsys,
           "argument --binning")
    assert not (tmp_path / "acc").exists()


# ------------------------------------------------------------------ item 7: messages


def test_a_background_gradient_is_named_not_the_stage_position(tmp_path):
    cols = np.arange(GEO.columns)
    folder = _plates(tmp_path / "grad", lambda f: np.clip(f + 300.0 * cols / cols[-1], 0, 4095).astype(np.uint16))
    res = calibrate_folder(folder)
    reasons = [r for f, r in res.skipped if "outlier" in r]
    assert reasons and all("background gradient" in r and "stage_mm" not in r for r in reasons), res.skipped


def test_a_hot_column_is_named(tmp_path, capsys):
    def hot(f):
        f = f.copy()
        f[:, 40] = 4000
        return f
    _fails(["calibrate", str(_plates(tmp_path / "hot", hot)), "--quiet"], capsys,
           "a constant column (column 40")


def test_saturated_stripes_say_saturated(tmp_path, capsys):
    folder = _plates(tmp_path / "sat", lambda f: np.clip(f.astype(np.float64) * 50, 0, 4095).astype(np.uint16))
    _fails(["calibrate", str(folder), "--quiet"], capsys, "only 0 usable", "10 × stripe saturated")


def test_model_general_uses_the_pixel_pitch_the_manifest_holds(tmp_path, capsys):
    """It was refused asking for lens.focal_length_mm and sensor.pixel_pitch_um that the manifest held."""
    rig = {"sensor": {"rows": GEO.rows, "columns": GEO.columns, "pixel_pitch_um": PITCH_8_UM, "adc_bits": 12}}
    folder = _plates(tmp_path / "g", rig=rig)
    capsys.readouterr()
    assert main(["calibrate", str(folder), "--quiet", "--model", "general", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["model"] == "general"


def test_csv_rows_for_files_not_given_are_named(tmp_path, capsys):
    files = _sources(tmp_path)
    (tmp_path / "pos.csv").write_text("file,stage_mm\np_0.png,0\np_10.png,1\np_20.png,2\np_99.png,9\n")
    assert main(["import", *map(str, files), "--positions", str(tmp_path / "pos.csv"), "--out",
                 str(tmp_path / "o")]) == 0
    assert "1 row(s) for files not given are left out: 'p_99.png'" in capsys.readouterr().err


def test_a_concurrent_import_into_the_same_folder_is_one_clear_line(tmp_path, monkeypatch):
    """Two imports at once: the second got a raw 'Directory not empty'."""
    import scheimpflug.io.importer as importer

    files = positions_from_names(_sources(tmp_path), "p_{stage_mm}.png")
    out = tmp_path / "o"
    real = importer.tempfile.mkdtemp

    def other_import_finishes_meanwhile(*args, **kwargs):
        (out / "frames").mkdir(parents=True)
        return real(*args, **kwargs)

    monkeypatch.setattr(importer.tempfile, "mkdtemp", other_import_finishes_meanwhile)
    with pytest.raises(FrameError, match="another import into the same folder"):
        import_frames(files, out)
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".o.")] == []


def test_a_calibration_of_an_unknown_model_is_refused(plate, tmp_path, capsys):
    _, cal = plate
    d = json.loads(cal.read_text())
    d["model"] = "magic"
    (tmp_path / "magic.json").write_text(json.dumps(d))
    scan = _scan_of(tmp_path / "scan", 1)
    _fails(["reconstruct", str(scan), "--calibration", str(tmp_path / "magic.json"), "--axis-mm", "150",
            "--out", str(tmp_path / "c.ply")], capsys, "\"model\": 'magic' is not a known model",
           "paper, general")


def test_calibration_files_without_the_new_fields_still_load(plate, tmp_path):
    _, cal = plate
    d = json.loads(cal.read_text())
    for key in ("pixel_pitch_um", "stage_range_mm"):
        d.pop(key)
    (tmp_path / "old.json").write_text(json.dumps(d))
    old = Calibration.load(tmp_path / "old.json")
    assert math.isnan(old.pixel_pitch_um) and old.constants() == Calibration.load(cal).constants()
    with pytest.raises(CalibrationError, match="pixel_pitch_um"):
        Calibration.from_json_dict({**d, "pixel_pitch_um": "x"})
    assert Path(cal).exists()
