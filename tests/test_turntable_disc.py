"""The turntable's disc in the twin (issue 35 item 5): keys, files, and its laser line.

The reference of the rendered line is independent of the renderer: FabScan's own
``config.json`` (its platform pose and laser plane in the stored frames' camera frame, as
:func:`scheimpflug.calibration.fabscan.read_fabscan` and the hand transform of
tests/test_fabscan_twin.py give them), the line where the laser plane crosses the table
plane, projected by ``cv2.projectPoints`` with FabScan's camera matrix and distortion.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh

from scheimpflug.app.cli import main
from scheimpflug.errors import RigError

REAL = Path(__file__).resolve().parents[2] / "shared" / "realdata"
CONFIG = REAL / "fabscan" / "dummy.config.json"
needs_config = pytest.mark.skipif(not CONFIG.is_file(), reason=f"FabScan's config absent ({CONFIG})")


def test_table_materials_are_the_parts_materials():
    from scenes import MATERIALS
    from scheimpflug.model.tables import TABLE_MATERIALS

    assert TABLE_MATERIALS == tuple(MATERIALS)


def test_disc_keys_default_to_no_disc_and_refuse_bad_values(paper_rig):
    from sim.backgrounds import table_parts

    assert paper_rig.stage.table_radius_mm == 0.0 and table_parts(paper_rig, 101) == ()
    rig = paper_rig.replace(stage={"table_radius_mm": 60.0, "table_thickness_mm": 8.0, "table_material": "marble"})
    (disc,) = table_parts(rig, 101)
    v = np.asarray(disc.mesh.vertices)
    assert disc.material == "marble" and disc.mesh.is_watertight
    assert v[:, 2].max() == pytest.approx(rig.stage.rotary_table_z_mm, abs=1e-12)     # its top: the table plane
    assert v[:, 2].min() == pytest.approx(rig.stage.rotary_table_z_mm - 8.0, abs=1e-12)
    assert np.hypot(v[:, 0], v[:, 1]).max() == pytest.approx(60.0, abs=1e-9)         # centred on the axis
    for change, words in (({"table_radius_mm": -1.0}, "table_radius_mm"),
                          ({"table_thickness_mm": 0.0}, "table_thickness_mm"),
                          ({"table_material": "wood"}, "table_material.*cardboard")):
        with pytest.raises(RigError, match=words):
            paper_rig.replace(stage=change)


@needs_config
def test_fabscan_rig_file_carries_its_table_radius_both_forms(tmp_path):
    """``rig from-calibration``: FabScan's ``turntable.radius`` (70 mm) in either form; the size a
    calibration does not give is marked unknown; the file by parts reads back into the same rig."""
    from scheimpflug.model.rig import load_rig

    a, b = tmp_path / "a.toml", tmp_path / "b.toml"
    assert main(["rig", "from-calibration", str(CONFIG), "--out", str(a)]) == 0
    assert main(["rig", "from-calibration", str(CONFIG), "--form", "parts", "--out", str(b)]) == 0
    assert "table_radius_mm = 70.0\n" in a.read_text()
    assert "table_thickness_mm = 10.0  # unknown" in a.read_text()
    assert "radius_mm = 70.0\n" in b.read_text() and "thickness_mm = 10.0  # unknown" in b.read_text()
    ra, rb = load_rig(a), load_rig(b)
    assert ra.stage.table_radius_mm == rb.stage.table_radius_mm == 70.0
    assert ra.stage == rb.stage
    bad = b.read_text().replace("[stage]\n", "[stage]\ntable_radius_mm = 5.0\n", 1)
    (tmp_path / "c.toml").write_text(bad)
    with pytest.raises(RigError, match="table_radius_mm.*turntable"):    # both named
        load_rig(tmp_path / "c.toml")


def _hidden_cube(path: Path) -> Path:
    """A 2 mm cube inside the disc's body, under its top: a rotary scan with nothing on the table."""
    mesh = trimesh.creation.box(extents=(2.0, 2.0, 1.0))
    mesh.apply_translation((0.0, 0.0, -5.0))
    mesh.export(path)
    return path


def _crossing_px(k, dist, normal, d_mm, p, w, radius_mm, n=4001) -> np.ndarray:
    """The table plane ∩ the laser plane within the disc, projected by OpenCV: (n, 2) pixel points."""
    along = np.cross(normal, w)
    along /= np.linalg.norm(along)
    # the point of the crossing line nearest the table's centre: n·x + d = 0, w·(x − p) = 0
    a = np.stack([normal, w, along])
    x0 = np.linalg.solve(a, [-d_mm, w @ p, along @ p])
    half = math.sqrt(max(radius_mm ** 2 - float(np.sum((x0 - p) ** 2)), 0.0))
    pts = x0 + np.outer(np.linspace(-half, half, n), along)
    pts = pts[pts[:, 2] > 0]
    return cv2.projectPoints(pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), k, dist)[0].reshape(-1, 2)


@needs_config
@pytest.mark.render
def test_laser_line_on_the_disc_where_the_sheet_crosses_the_table(tmp_path, variant):
    """The disc's rendered line, per column, on the exact crossing projected by OpenCV (module
    docstring), within 0.3 px RMS at binning 4; the truth's per-column stripe on it too."""
    from scheimpflug.calibration.fabscan import read_fabscan

    rig = tmp_path / "rig.toml"
    assert main(["rig", "from-calibration", str(CONFIG), "--preset", "rpi-v2-binned", "--fabscan-distortion", "apply",
                 "--out", str(rig)]) == 0
    out = tmp_path / "scan"
    assert main(["render", "rotary", "--rig", str(rig), "--part", str(_hidden_cube(tmp_path / "cube.stl")),
                 "--step-deg", "180", "--frames", "1", "--binning", "4", "--truth-pixels", "none",
                 "--out", str(out), "--quiet"]) == 0
    man = json.loads((out / "manifest.json").read_text())
    assert man["scenario_params"]["table"]["radius_mm"] == 70.0
    # the reference: FabScan's platform and laser plane in the stored frames' camera frame
    d = json.loads(CONFIG.read_text())["calibration"]
    m = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])   # rotate, hflip: X = Y_fab, Y = −X_fab
    p, w = m @ np.asarray(d["platform_translation"]), m @ np.asarray(d["platform_rotation"])[:, 2]
    cal = read_fabscan(CONFIG, distortion="apply")
    plane = np.asarray(cal.laser_plane, np.float64)
    k = cal.camera.camera_matrix.copy()
    k[:2] /= 4.0
    k[:2, 2] -= 1.5 / 4.0                                      # pixel centres of a 4 × 4 bin
    uv = _crossing_px(k, cal.camera.dist_coeffs[:5], plane[:3], plane[3], p, w, 70.0)
    uv = uv[np.argsort(uv[:, 0])]
    image = cv2.imread(str(out / "frames" / "00000.png"), cv2.IMREAD_UNCHANGED).astype(np.float64)
    truth = np.load(out / "truth" / "00000.npz")
    disc_id = man["scenario_params"]["table"]["object_id"]
    cols = np.flatnonzero((truth["stripe_object_id"] == disc_id) & (truth["stripe_count"] == 1))
    cols = cols[(cols > uv[0, 0] + 2) & (cols < uv[-1, 0] - 2)]          # off the disc's rim
    assert len(cols) > 40
    v_ref = np.interp(cols, uv[:, 0], uv[:, 1])
    assert np.abs(truth["stripe_u"][cols] - v_ref).max() < 0.01          # the truth: the same crossing
    win = np.arange(image.shape[0])[:, None]
    near = np.abs(win - v_ref) <= 6                                      # the column's stripe, ±6 px
    prof = np.where(near, image[:, cols], 0.0)
    wgt = np.clip(prof - 0.1 * prof.max(axis=0), 0.0, None)
    centroid = (wgt * win).sum(axis=0) / wgt.sum(axis=0)
    rms = math.sqrt(float(np.mean((centroid - v_ref) ** 2)))
    print(f"disc line: {len(cols)} columns, RMS {rms:.3f} px, mean {np.mean(centroid - v_ref):+.3f} px")
    assert rms < 0.3
