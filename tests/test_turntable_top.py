"""The turntable's top found from its line (scheimpflug.turntable_top) and the twin's tilted disc that turns.

References, each independent of the code under test: lines built here as the exact crossing of
a plane (its normal turned by scipy's ``Rotation``) with the sheet, projected by a pinhole or by
``cv2.projectPoints``; the closed form of the still top's height (a weighted mean); FabScan's
own ``config.json`` for the table's pose.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from scheimpflug.app.cli import main
from scheimpflug.errors import RigError

REAL = Path(__file__).resolve().parents[2] / "shared" / "realdata"
CONFIG = REAL / "fabscan" / "dummy.config.json"
needs_config = pytest.mark.skipif(not CONFIG.is_file(), reason=f"FabScan's config absent ({CONFIG})")


def _normal(frame, angle_deg, tilt_deg, azimuth_deg, lean_deg=0.0, lean_azimuth_deg=0.0):
    """The top's normal in the camera frame, by scipy (module docstring): R_cam · R_b · R_z(θ) · n0."""
    def lean(t, p):
        return Rotation.from_rotvec(math.radians(t) * np.array([-math.sin(math.radians(p)),
                                                                 math.cos(math.radians(p)), 0.0]))
    n = (lean(lean_deg, lean_azimuth_deg) * Rotation.from_euler("z", angle_deg, degrees=True)
         * lean(tilt_deg, azimuth_deg)).apply([0.0, 0.0, 1.0])
    return frame[:3, :3] @ n


def _crossing(n_top, q_top, n_sheet, d_sheet, centre, half_mm, n=60):
    """The line top ∩ sheet (n·x = n·q, n_s·x = d): ``half_mm`` either side of its point nearest ``centre``."""
    d = np.cross(n_top, n_sheet)
    d /= np.linalg.norm(d)
    x0 = np.linalg.solve(np.stack([n_top, n_sheet, d]), [n_top @ q_top, d_sheet, d @ centre])
    return x0 + np.outer(np.linspace(-half_mm, half_mm, n), d)


@pytest.fixture(scope="module")
def scene():
    """A pinhole calibration (640 × 480) with its sheet, and a table frame whose axis lies in the sheet."""
    from scheimpflug.calibration.camera import OpenCVCamera
    from scheimpflug.calibration.model import sheet_frame_from_plane
    from scheimpflug.calibration.target import TargetCalibration

    k = np.array([[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]])
    n = np.array([0.7, 0.1, 0.5])
    n /= np.linalg.norm(n)
    plane = np.array([*n, -120.0])
    origin, e_s, e_h = sheet_frame_from_plane(plane)
    cal = TargetCalibration(camera=OpenCVCamera(k, np.zeros(5)), homography=np.column_stack([e_s, e_h, origin]),
                            columns=640, rows=480, n_frames=0, laser_plane=plane, pattern="chessboard:9x6:10")
    z = e_h / np.linalg.norm(e_h)                    # the axis, in the sheet
    x = np.cross(z, n)                               # the table's x: ⊥ the axis (here ⊥ the sheet too)
    frame = np.eye(4)
    frame[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    frame[:3, 3] = origin - 20.0 * z
    return cal, k, n, 120.0, frame


def _points(scene, rng, angles, h, tilt, az, lean=0.0, lean_az=0.0, noise_px=0.2):
    """Every frame's line points, projected, noised along the column, mapped back onto the sheet."""
    cal, k, n_s, d_s, frame = scene
    z, o = frame[:3, 2], frame[:3, 3]
    us, vs, fs = [], [], []
    for i, a in enumerate(angles):
        p = _crossing(_normal(frame, a, tilt, az, lean, lean_az), o + h * z, n_s, d_s, o, 30.0)
        uv = p[:, :2] / p[:, 2:] * k[0, 0] + k[:2, 2]
        us.append(uv[:, 0])
        vs.append(uv[:, 1] + noise_px * rng.standard_normal(len(uv)))
        fs.append(np.full(len(uv), i))
    u, v, f = (np.concatenate(x) for x in (us, vs, fs))
    x = cal.camera_from_pixel(u, v)
    g = (cal.camera_from_pixel(u, v + 0.5) - cal.camera_from_pixel(u, v - 0.5))
    return x, g, f


def _line_azimuth_deg(scene) -> float:
    """The azimuth of the flat top's line (the sheet ∩ the table plane) in the table frame."""
    _, _, n_s, _, frame = scene
    d = np.cross([0.0, 0.0, 1.0], frame[:3, :3].T @ n_s)
    return math.degrees(math.atan2(d[1], d[0]))


def test_tilted_top_recovered_from_its_lines(scene, rng):
    """Known h, lean (toward the line: the one lean a line shows), τ, ψ (36 angles, 0.1 px of noise) →
    the fit finds h, the lean and τ within 0.01 mm and 0.01°, ψ within 2° (its standard error < 1°),
    each within 4 of its standard errors; the residual is the noise's."""
    from scheimpflug.turntable_top import fit_table_top

    angles = np.arange(0.0, 360.0, 10.0)
    lean_az = _line_azimuth_deg(scene) + 180.0
    truth = dict(h=0.7, tilt=0.25, az=125.0, lean=0.6, lean_az=lean_az)
    x, g, f = _points(scene, rng, angles, **truth, noise_px=0.1)
    top = fit_table_top(x, g, f, angles, scene[4])
    assert top.n_frames == 36 and top.n_points == 2160
    assert abs(top.offset_mm - 0.7) < min(0.01, 4 * top.offset_se_mm + 1e-4)
    assert abs(top.tilt_deg - 0.25) < min(0.01, 4 * top.tilt_se_deg + 1e-4)
    assert top.azimuth_se_deg < 1.0
    assert abs((top.azimuth_deg - 125.0 + 180.0) % 360.0 - 180.0) < min(2.0, 4 * top.azimuth_se_deg + 1e-3)
    fitted = top.lean_deg * np.array([math.cos(math.radians(top.lean_azimuth_deg)),
                                      math.sin(math.radians(top.lean_azimuth_deg))])
    true = 0.6 * np.array([math.cos(math.radians(lean_az)), math.sin(math.radians(lean_az))])
    assert np.linalg.norm(fitted - true) < min(0.01, 4 * top.lean_se_deg + 1e-4)
    assert 0.08 < top.rms_px < 0.12
    keys = top.rig_keys()
    assert set(keys) == {"table_top_offset_mm", "table_tilt_deg", "table_tilt_azimuth_deg", "table_axis_tilt_deg",
                         "table_axis_tilt_azimuth_deg"}


def test_flat_top_is_the_closed_form(scene, rng):
    """τ = 0, no lean: h alone is the weighted mean of the points' heights (weights 1/(∂z/∂v)²), to 1e-9 mm;
    with every parameter free on exact points, τ and the lean come out 0 and h exact."""
    from scheimpflug.turntable_top import fit_table_top

    angles = np.arange(0.0, 360.0, 45.0)
    x, g, f = _points(scene, rng, angles, h=-1.3, tilt=0.0, az=0.0, noise_px=0.3)
    frame = scene[4]
    z = (x - frame[:3, 3]) @ frame[:3, 2]
    gz = g @ frame[:3, 2]
    closed = float(np.sum(z / gz ** 2) / np.sum(1.0 / gz ** 2))
    top = fit_table_top(x, g, f, angles, frame, fit_tilt=False, fit_lean=False)
    assert abs(top.offset_mm - closed) < 1e-9 and abs(closed + 1.3) < 0.01
    assert top.tilt_deg == 0.0 and top.lean_deg == 0.0 and math.isinf(top.azimuth_se_deg)
    assert top.to_json_dict()["azimuth_se_deg"] is None                 # JSON-ready: no inf
    x, g, f = _points(scene, rng, angles, h=-1.3, tilt=0.0, az=0.0, noise_px=0.0)
    top = fit_table_top(x, g, f, angles, frame)
    assert abs(top.offset_mm + 1.3) < 1e-9 and top.tilt_deg < 1e-7 and top.lean_deg < 1e-7 and top.rms_px < 1e-9


def test_table_top_refuses_what_cannot_be_fitted(scene, rng):
    from scheimpflug.turntable_top import fit_table_top

    x, g, f = _points(scene, rng, [10.0], h=0.0, tilt=0.2, az=0.0)
    with pytest.raises(ValueError, match="two table angles"):
        fit_table_top(x, g, f, [10.0], scene[4])
    with pytest.raises(ValueError, match=r"expected \(n, 3\)"):
        fit_table_top(x[:, :2], g, f, [10.0], scene[4])
    with pytest.raises(ValueError, match="at least 8 finite points"):
        fit_table_top(x[:3], g[:3], f[:3], [10.0, 20.0], scene[4])


def test_table_keys_default_to_the_square_top_and_refuse_bad_values(paper_rig):
    from sim.backgrounds import table_parts, turns_with_table
    from sim.stages import stage_from_part, translation

    rig = paper_rig.replace(stage={"table_radius_mm": 60.0, "runout_um": 40.0})
    st = rig.stage
    assert (st.table_top_offset_mm, st.table_tilt_deg, st.table_tilt_azimuth_deg, st.table_axis_tilt_deg,
            st.table_axis_tilt_azimuth_deg) == (0.0,) * 5
    (disc,) = table_parts(rig, 101)
    assert not turns_with_table(disc) and "turns_with_table" not in disc.analytic
    # exact: same run — the disc of the defaults is the one before these keys, bit for bit
    assert np.array_equal(np.asarray(disc.analytic["stage_from_table"]),
                          stage_from_part(rig, 0.0) @ translation((-0.02, 0.0, 0.0)))
    (high,) = table_parts(rig.replace(stage={"table_top_offset_mm": 1.5, "table_axis_tilt_deg": 2.0}), 101)
    assert not turns_with_table(high)                       # square to its own axis: still
    (tilted,) = table_parts(rig.replace(stage={"table_tilt_deg": 1.0}), 101)
    assert turns_with_table(tilted)
    for change, words in (({"table_tilt_deg": 12.0}, "table_tilt_deg"),
                          ({"table_axis_tilt_deg": -1.0}, "table_axis_tilt_deg"),
                          ({"table_top_offset_mm": 200.0}, "table_top_offset_mm")):
        with pytest.raises(RigError, match=words):
            paper_rig.replace(stage=change)


# ---------------------------------------------------------------- the twin's disc


def _hidden_cube(path: Path) -> Path:
    """A 2 mm cube inside the disc's body, under its top: a rotary scan with nothing on the table."""
    mesh = trimesh.creation.box(extents=(2.0, 2.0, 1.0))
    mesh.apply_translation((0.0, 0.0, -5.0))
    mesh.export(path)
    return path


def _fabscan_rig(tmp_path, distortion: str, keys: dict) -> Path:
    """FabScan's rig with its 70 mm disc, the table keys set."""
    out = tmp_path / f"rig-{distortion}.toml"
    assert main(["rig", "from-calibration", str(CONFIG), "--preset", "rpi-v2-binned", "--fabscan-distortion",
                 distortion, "--out", str(out)]) == 0
    text = out.read_text()
    for k, v in keys.items():
        assert f"\n{k} = 0.0\n" in text
        text = text.replace(f"\n{k} = 0.0\n", f"\n{k} = {v!r}\n")
    out.write_text(text)
    return out


TILTED = {"table_top_offset_mm": 0.8, "table_tilt_deg": 1.5, "table_tilt_azimuth_deg": 40.0,
          "table_axis_tilt_deg": 0.6, "table_axis_tilt_azimuth_deg": -70.0}


@needs_config
@pytest.mark.render
def test_tilted_disc_turns_and_its_line_is_the_exact_crossing(tmp_path, variant):
    """A tilted disc at 0° and 90° (binning 4): per column, the truth on the exact top ∩ laser plane
    projected by OpenCV within 0.01 px, the image's centroids within 0.3 px RMS; the line moves."""
    from scheimpflug.calibration.fabscan import read_fabscan
    from scheimpflug.model.rig import load_rig
    from sim.backgrounds import camera_from_table

    rig_path = _fabscan_rig(tmp_path, "apply", TILTED)
    out = tmp_path / "scan"
    assert main(["render", "rotary", "--rig", str(rig_path), "--part", str(_hidden_cube(tmp_path / "cube.stl")),
                 "--step-deg", "90", "--frames", "2", "--binning", "4", "--truth-pixels", "none",
                 "--out", str(out), "--quiet"]) == 0
    man = json.loads((out / "manifest.json").read_text())
    assert man["scenario_params"]["table"]["turns_with_table"] is True
    # the table frame at 0°: its origin and up are FabScan's platform (by hand, tests/test_fabscan_twin.py)
    frame = camera_from_table(load_rig(rig_path))
    d = json.loads(CONFIG.read_text())["calibration"]
    m = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    assert np.abs(frame[:3, 3] - m @ np.asarray(d["platform_translation"])).max() < 1e-9
    assert np.abs(frame[:3, 2] - m @ np.asarray(d["platform_rotation"])[:, 2]).max() < 1e-9
    cal = read_fabscan(CONFIG, distortion="apply")
    plane = np.asarray(cal.laser_plane, np.float64)
    k = cal.camera.camera_matrix.copy()
    k[:2] /= 4.0
    k[:2, 2] -= 1.5 / 4.0                                      # pixel centres of a 4 × 4 bin
    disc_id = man["scenario_params"]["table"]["object_id"]
    q = frame[:3, 3] + TILTED["table_top_offset_mm"] * frame[:3, 2]
    refs = []
    for i, angle in enumerate((0.0, 90.0)):
        n = _normal(frame, angle, TILTED["table_tilt_deg"], TILTED["table_tilt_azimuth_deg"],
                    TILTED["table_axis_tilt_deg"], TILTED["table_axis_tilt_azimuth_deg"])
        p = _crossing(n, q, plane[:3], -plane[3], q, 75.0, n=4001)
        p = p[np.linalg.norm(p - q, axis=1) < 70.0]
        uv = cv2.projectPoints(p.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), k,
                               cal.camera.dist_coeffs[:5])[0].reshape(-1, 2)
        uv = uv[np.argsort(uv[:, 0])]
        image = cv2.imread(str(out / "frames" / f"{i:05d}.png"), cv2.IMREAD_UNCHANGED).astype(np.float64)
        truth = np.load(out / "truth" / f"{i:05d}.npz")
        cols = np.flatnonzero((truth["stripe_object_id"] == disc_id) & (truth["stripe_count"] == 1))
        cols = cols[(cols > uv[0, 0] + 2) & (cols < uv[-1, 0] - 2)]          # off the disc's rim
        assert len(cols) > 40
        v_ref = np.interp(cols, uv[:, 0], uv[:, 1])
        assert np.abs(truth["stripe_u"][cols] - v_ref).max() < 0.01          # the truth: that frame's crossing
        win = np.arange(image.shape[0])[:, None]
        prof = np.where(np.abs(win - v_ref) <= 6, image[:, cols], 0.0)
        wgt = np.clip(prof - 0.1 * prof.max(axis=0), 0.0, None)
        centroid = (wgt * win).sum(axis=0) / wgt.sum(axis=0)
        rms = math.sqrt(float(np.mean((centroid - v_ref) ** 2)))
        print(f"tilted disc at {angle:g}°: {len(cols)} columns, RMS {rms:.3f} px, mean "
              f"{np.mean(centroid - v_ref):+.3f} px")
        assert rms < 0.3
        refs.append((cols, v_ref))
    common = np.intersect1d(refs[0][0], refs[1][0])
    moved = np.interp(common, *refs[1]) - np.interp(common, *refs[0])
    assert np.abs(moved).max() > 2.0                          # it wobbles: the line moved between the angles


@needs_config
@pytest.mark.slow
@pytest.mark.render
def test_rig_housing_table_finds_the_twins_top_again(tmp_path, variant):
    """Twin frames of a disc with known keys (FabScan's rig, its own camera model, 6 angles) →
    ``rig housing --table --rig`` writes keys within 0.01 mm, 0.01° and 1° of them (measured 2026-12-07:
    h +0.4003 mm, τ 0.3014°, ψ 59.73°, lean 0.0001°; residual 0.52 px RMS, the cardboard's stripe noise)."""
    from scheimpflug.model.rig import load_rig

    truth = {"table_top_offset_mm": 0.4, "table_tilt_deg": 0.3, "table_tilt_azimuth_deg": 60.0}
    rig_path = _fabscan_rig(tmp_path, "as-fabscan", truth)
    out = tmp_path / "scan"
    assert main(["render", "rotary", "--rig", str(rig_path), "--part", str(_hidden_cube(tmp_path / "cube.stl")),
                 "--step-deg", "60", "--frames", "6", "--truth-pixels", "none", "--out", str(out), "--quiet"]) == 0
    man = json.loads((out / "manifest.json").read_text())
    ids = np.load(out / "truth" / "00000.npz")["stripe_object_id"]
    cols = np.flatnonzero(ids == man["scenario_params"]["table"]["object_id"])
    (tmp_path / "fit").mkdir()
    fit = _fabscan_rig(tmp_path / "fit", "as-fabscan", {})
    assert main(["rig", "housing", str(out), "--calibration", str(CONFIG), "--fabscan-distortion", "as-fabscan",
                 "--table", f"{cols.min() + 10}:{cols.max() - 10}", "--rig", str(fit)]) == 0
    st = load_rig(fit).stage
    print(f"found: h {st.table_top_offset_mm:+.4f} mm, tilt {st.table_tilt_deg:.4f}° toward "
          f"{st.table_tilt_azimuth_deg:.2f}°, lean {st.table_axis_tilt_deg:.4f}°")
    assert abs(st.table_top_offset_mm - 0.4) < 0.01
    assert abs(st.table_tilt_deg - 0.3) < 0.01
    assert abs((st.table_tilt_azimuth_deg - 60.0 + 180.0) % 360.0 - 180.0) < 1.0
    assert st.table_axis_tilt_deg < 0.01
    assert "# table keys fitted by scheimpflug rig housing" in fit.read_text()


@pytest.mark.parametrize("args, words", [
    (["--walls", "0:10"], "--walls needs --out"),
    (["--table", "0:10"], "--table needs --rig"),
    (["--table", "0:10", "--rig", "r.toml", "--out", "h.toml"], "--out is the housing file of --walls"),
    ([], "give --walls"),
    (["--table", "10:0", "--rig", "r.toml"], "first column must be below"),
])
def test_rig_housing_refuses_incomplete_options(tmp_path, capsys, args, words):
    assert main(["rig", "housing", str(tmp_path), "--calibration", "c.json", *args]) != 0
    assert words in capsys.readouterr().err
