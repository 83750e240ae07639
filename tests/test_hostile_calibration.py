"""Hostile cases of calibration (issue 12 items 3, 5, 6, 7 and the manifest/option tracebacks).

Synthetic plate frames from the closed forms (``synth_frames``) on an 8 × 8 binned paper
geometry (152 × 242 px) keep these fast.
"""

import json
import math
import warnings

import cv2
import numpy as np
import pytest
from synth_frames import F2_NOMINAL, Geometry, calibration_folder, rig_dict, write_folder

from scheimpflug.app.cli import main
from scheimpflug.calibration import Calibration, CalibrationTolerances, calibrate_folder
from scheimpflug.errors import CalibrationError

GEO = Geometry(hinge_u_px=399.5, hinge_v_px=96.375, F2_px_mm=F2_NOMINAL / 8, columns=152, rows=242)
STAGES = np.arange(60.0, 250.0, 20.0)          # 10 frames, both plate edges in view


@pytest.fixture(autouse=True)
def _quiet_skips():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    path, _ = calibration_folder(tmp_path_factory.mktemp("cal") / "c", GEO, stages=STAGES, seed=3)
    return path


def _manifest(path):
    return json.loads((path / "manifest.json").read_text())


def _copy_with(folder, dst, edit):
    """A copy of ``folder`` whose manifest ``edit(manifest)`` changed."""
    import shutil

    shutil.copytree(folder, dst)
    m = _manifest(dst)
    edit(m)
    (dst / "manifest.json").write_text(json.dumps(m))
    return dst


def _fails(args, capsys, *needles):
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for n in needles:
        assert n in err, err
    return err


def test_exactly_determined_fit_has_no_sigma_and_is_not_preferred(tmp_path, capsys):
    """Item 5: 3 frames make the refined fit exactly determined: σ undefined (null), paper preferred."""
    path, _ = calibration_folder(tmp_path / "three", GEO, stages=[80.0, 150.0, 230.0], seed=4)
    res = calibrate_folder(path)
    assert len(res.measurements) == 3
    assert math.isnan(res.refined.hinge_u_sigma_px) and math.isnan(res.refined.F2_sigma_px_mm)
    assert math.isfinite(res.paper.hinge_u_sigma_px) and res.paper.hinge_u_sigma_px > 0.01
    assert res.best is res.paper
    assert any("recommended: at least 6" in w for w in res.warnings)
    assert any("undefined" in w and "paper" in w for w in res.warnings)
    out = tmp_path / "cal.json"
    assert main(["calibrate", str(path), "--json", "--quiet", "--out", str(out)]) == 0
    cap = capsys.readouterr()
    d = json.loads(cap.out)
    assert d["method"] == "paper" and d["refined"]["hinge_u_sigma_px"] is None
    assert d["refined"]["F2_sigma_px_mm"] is None and "recommended" in cap.err
    assert math.isnan(Calibration.from_json_dict(d["refined"]).hinge_u_sigma_px)   # null reads back
    assert Calibration.load(out).method == "paper"


def test_four_frames_have_a_sigma_and_a_warning(tmp_path):
    path, _ = calibration_folder(tmp_path / "four", GEO, stages=[70.0, 120.0, 170.0, 230.0], seed=5)
    res = calibrate_folder(path)
    assert math.isfinite(res.refined.hinge_u_sigma_px) and res.refined.hinge_u_sigma_px > 0
    assert any("1 degree(s) of freedom" in w for w in res.warnings)


def test_duplicate_stage_position_is_refused_naming_both_frames(folder, tmp_path, capsys):
    """Item 6: a typo repeating a stage position (the stripes differ) is refused, not averaged."""
    def dup(m):
        m["frames"][5]["stage_mm"] = m["frames"][4]["stage_mm"]
    bad = _copy_with(folder, tmp_path / "dup", dup)
    with pytest.raises(CalibrationError, match=r"00004.png and frames/00005.png have the same stage"):
        calibrate_folder(bad)
    _fails(["calibrate", str(bad), "--quiet"], capsys, "same stage position", "00005.png")


def test_swapped_stage_positions_are_refused(folder, tmp_path):
    def swap(m):
        f = m["frames"]
        f[2]["stage_mm"], f[6]["stage_mm"] = f[6]["stage_mm"], f[2]["stage_mm"]
    with pytest.raises(CalibrationError, match="disagree.*wrong or swapped"):
        calibrate_folder(_copy_with(folder, tmp_path / "swap", swap))


def test_one_wrong_stage_position_is_an_outlier_named_and_left_out(folder, tmp_path):
    """Item 6: 3.5 mm off in one frame (still in order): left out by the residual test, named."""
    clean = calibrate_folder(folder)
    assert not [s for s in clean.skipped if "outlier" in s[1]]

    def typo(m):
        m["frames"][5]["stage_mm"] += 3.5
    bad = _copy_with(folder, tmp_path / "typo", typo)
    res = calibrate_folder(bad)
    outliers = [s for s in res.skipped if "outlier in the distance fit" in s[1]]
    assert [f for f, _ in outliers] == ["frames/00005.png"] and "stage_mm" in outliers[0][1]
    # exactly the calibration without that frame …
    without = calibrate_folder(_copy_with(folder, tmp_path / "without", lambda m: m["frames"].pop(5)))
    assert res.best.d0_mm == pytest.approx(without.best.d0_mm, abs=1e-9)
    assert len(res.measurements) == len(clean.measurements) - 1
    # … while the typo kept would move d0 by ≈ 0.8 mm (the silent error of the issue)
    kept = calibrate_folder(bad, tol=CalibrationTolerances(fit_outlier_ratio=math.inf))
    assert abs(kept.best.d0_mm - clean.best.d0_mm) > 0.5 > abs(res.best.d0_mm - clean.best.d0_mm)


def test_flipped_frames_get_a_hint(folder, tmp_path, capsys):
    flipped = tmp_path / "flip"
    import shutil

    shutil.copytree(folder, flipped)
    for p in sorted((flipped / "frames").glob("*.png")):
        cv2.imwrite(str(p), cv2.flip(cv2.imread(str(p), cv2.IMREAD_UNCHANGED), 1))
    _fails(["calibrate", str(flipped), "--quiet"], capsys, "flipped left–right")


def test_all_saturated_frames_say_saturated(tmp_path, capsys):
    frames = [np.full((GEO.rows, GEO.columns), 4095, np.uint16) for _ in range(4)]
    path = write_folder(tmp_path / "sat", frames, [{"stage_mm": float(s)} for s in STAGES[:4]],
                        rig=rig_dict(GEO))
    res_err = _fails(["calibrate", str(path), "--quiet"], capsys, "only 0 usable")
    assert "0 usable" in res_err
    with pytest.warns(UserWarning, match="frame saturated .100 % of the pixels"):
        with pytest.raises(CalibrationError):
            warnings.simplefilter("always")
            calibrate_folder(path)


@pytest.mark.parametrize("cal_edit, needle", [
    (lambda d: d.update(hinge_px=[100.0, 96.0]), "inside the 152-column sensor"),  # hinge on the sensor
    (lambda d: d.update(F2_px_mm=1.7e5), "F2_px_mm = 170000 must be < 0"),
    (lambda d: d.update(C_mm=-3.0), "C_mm = -3 must be > 0"),
    (lambda d: d.update(d0_mm=float("inf")), "d0_mm = inf must be finite"),
    (lambda d: d.update(d0_mm="abc"), "garbles a field"),
    (lambda d: d.update(columns=1e400), "garbles a field"),
    (lambda d: d.update(C_sigma_mm=-1.0), "C_sigma_mm = -1.0 must be >= 0"),
    (lambda d: d.update(hinge_px=[float("nan"), 96.0]), "hinge_u_px = nan must be finite"),
])
def test_calibration_files_are_validated_on_load(folder, tmp_path, capsys, cal_edit, needle):
    """Item 7: an impossible calibration file is refused by name, not applied (axis −2943 mm)."""
    good = calibrate_folder(folder).best.to_json_dict()
    cal_edit(good)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(good))
    with pytest.raises(CalibrationError, match="bad.json"):
        Calibration.load(path)
    _fails(["axis", str(folder), "--calibration", str(path)], capsys, needle)


def test_a_hinge_inside_the_frames_of_an_unknown_size_calibration_is_refused(folder, tmp_path, capsys):
    good = calibrate_folder(folder).best.to_json_dict()
    good.update(columns=0, rows=0, hinge_px=[100.0, 96.0])
    (tmp_path / "c.json").write_text(json.dumps(good))
    Calibration.load(tmp_path / "c.json")                         # nothing to check it against …
    blk = write_folder(tmp_path / "b", [np.zeros((GEO.rows, GEO.columns), np.uint16)],
                       [{"angle_deg": 0.0}], scenario="blocker", rig=rig_dict(GEO))
    _fails(["axis", str(blk), "--calibration", str(tmp_path / "c.json")], capsys,
           "cannot be applied", "inside the 152-column sensor")           # … until it meets frames


@pytest.mark.parametrize("edit, needle", [
    (lambda m: m["rig"]["sensor"].update(rows=float("inf")), "rig.sensor.rows = inf must be an integer"),
    (lambda m: m["rig"]["sensor"].update(adc_bits=float("nan")), "rig.sensor.adc_bits = nan"),
    (lambda m: m["rig"]["sensor"].update(columns=10 ** 7), "rig.sensor.columns = 10000000"),
    (lambda m: m["scenario_params"].update(plate_height_mm="abc"), "scenario_params.plate_height_mm = 'abc'"),
    (lambda m: m["scenario_params"].update(plate_height_mm=None), "plate_height_mm = None"),
    (lambda m: m["scenario_params"].update(plate_height_mm={}), "plate_height_mm = {}"),
    (lambda m: m["rig"]["sensor"].update(pixel_pitch_um=1.3e157), "pixel_pitch_um = 1.3e+157"),  # fuzz
    (lambda m: m["rig"].update(lens=[55]), "rig.lens must be an object"),
])
def test_manifest_values_that_are_not_what_they_claim(folder, tmp_path, capsys, edit, needle):
    bad = _copy_with(folder, tmp_path / "m", edit)
    _fails(["calibrate", str(bad), "--quiet"], capsys, needle)


def test_outputs_that_are_inputs_are_refused_and_force_overwrites(folder, tmp_path, capsys):
    """Item 3: --out over the folder's own files is refused; an existing output needs --force."""
    before = (folder / "manifest.json").read_bytes()
    _fails(["calibrate", str(folder), "--quiet", "--out", str(folder / "manifest.json")], capsys,
           "lies among the files of the input frame folder")
    _fails(["calibrate", str(folder), "--quiet", "--out", str(folder / "frames" / "00000.png")], capsys,
           "(frames)")
    assert (folder / "manifest.json").read_bytes() == before  # exact: copy
    _fails(["calibrate", str(folder), "--quiet", "--out", str(tmp_path)], capsys, "is a folder")
    _fails(["calibrate", str(folder), "--quiet", "--plot", str(tmp_path / "x.xyz")], capsys,
           "unknown image format .xyz")
    out = tmp_path / "cal.json"
    out.write_text("{}")
    _fails(["calibrate", str(folder), "--quiet", "--out", str(out)], capsys, "--force")
    assert out.read_text() == "{}"
    assert main(["calibrate", str(folder), "--quiet", "--out", str(out), "--force"]) == 0
    assert Calibration.load(out).n_frames == len(calibrate_folder(folder).measurements)
    assert main(["calibrate", str(folder), "--quiet", "--out", str(folder / "cal.json")]) == 0  # beside: fine


@pytest.mark.parametrize("value", ["inf", "nan", "0", "-89", "abc"])
def test_plate_height_option_is_validated(folder, capsys, value):
    _fails(["calibrate", str(folder), "--quiet", "--plate-height-mm", value], capsys,
           "argument --plate-height-mm")
