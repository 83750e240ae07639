"""``twin build`` and ``render rotary --twin`` (issue 36 items 1 and 2) on a scan the twin rendered itself.

The scan: FabScanPi's rig from its own calibration (``dummy.config.json``, 1640 × 1232, the
stripe along the rows, its 70 mm table disc), a 40 × 30 × 60 mm box standing off the axis
(its faces at x = −10 … 30, y = −10 … 20 mm of the part frame), and two housing boards (the
two still walls ``twin build`` found in the real ``scan-2_1``, copied below with that
provenance), rendered at 8 angles.  The references are independent of ``twin build``: the
box's own faces (the part's model must lie on them, in the part frame the renderer places
parts in), the two boards' 3-D lines, and the scan's own frames (the twin of this scan,
rendered at the scan's angles, puts the stripe where the scan has it).  Skipped, saying so,
where FabScan's config (``../shared/realdata``) is absent.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from scheimpflug.app.cli import EXIT_ERROR, main
from scheimpflug.model.rigfile import with_stage_keys

REAL = Path(__file__).resolve().parents[2] / "shared" / "realdata"
CONFIG = REAL / "fabscan" / "dummy.config.json"
pytestmark = [pytest.mark.render,
              pytest.mark.skipif(not CONFIG.is_file(), reason=f"FabScan's config absent ({CONFIG})")]

BOX_LO, BOX_HI = np.array([-10.0, -10.0, 0.0]), np.array([30.0, 20.0, 60.0])
#: the still walls of scan-2_1 as ``twin build`` found them (calibration's camera frame [mm]):
#: ``twin build ../shared/realdata/... scan-2_1 (200 frames imported) --calibration dummy.config.json``
WALLS = (("wall_a", [-82.0299, 26.1948, 156.1291], [0.999345, -0.035974, -0.004005], [0.025277, 0.614374, 0.788610],
          52.25),
         ("wall_b", [-69.1944, 42.7084, 177.8381], [0.097816, -0.614134, -0.783116], [0.994867, 0.039856, 0.093009],
          25.62))
ANGLES = "0:45"
TABLE_RADIUS_MM = 55.0


def _box_stl(path: Path) -> Path:
    import trimesh

    box = trimesh.creation.box(extents=BOX_HI - BOX_LO)
    box.apply_translation(0.5 * (BOX_LO + BOX_HI))
    box.export(path)
    return path


def _housing(path: Path) -> Path:
    from scheimpflug.model.housing import Board, housing_to_toml

    boards = [Board(n, np.array(c), np.array(nm) / np.linalg.norm(nm), np.array(d) / np.linalg.norm(d), length,
                    60.0) for n, c, nm, d, length in WALLS]
    path.write_text(housing_to_toml(boards, "scan-2_1's walls (test_twin_build)"))
    return path


@pytest.fixture(scope="module")
def box_scan(tmp_path_factory, variant):
    tmp = tmp_path_factory.mktemp("twin_build")
    rig = tmp / "fabscan.toml"
    assert main(["rig", "from-calibration", str(CONFIG), "--preset", "rpi-v2-binned", "--out", str(rig)]) == 0
    # a disc smaller than FabScan's 70 mm, so that its rim shows in the frames (as the real one's does)
    rig.write_text(with_stage_keys(rig.read_text(), {"table_radius_mm": TABLE_RADIUS_MM}, "test_twin_build's disc"))
    scan = tmp / "scan"
    assert main(["render", "rotary", "--rig", str(rig), "--part", str(_box_stl(tmp / "box.stl")),
                 f"--angles-deg={ANGLES}", "--housing", str(_housing(tmp / "walls.toml")), "--truth-pixels", "none",
                 "--out", str(scan), "--quiet"]) == 0
    twin = tmp / "twin"
    assert main(["twin", "build", str(scan), "--calibration", str(CONFIG), "--preset", "rpi-v2-binned", "--out",
                 str(twin), "--no-identify", "--quiet"]) == 0
    return tmp, scan, twin


def test_twin_build_writes_the_layout(box_scan):
    _, scan, twin = box_scan
    meta = json.loads((twin / "twin.json").read_text())
    assert meta["format"] == "scheimpflug-twin/1" and meta["complete"] is True
    assert meta["angles_deg"] == [45.0 * k for k in range(8)]
    assert meta["steps"]["identify"] == {"status": "not run", "reason": "--no-identify"}
    assert meta["identified"] is None and meta["files"]["identified_rig"] is None
    # the part's material: the default translucent tag and, without an identification, its tabulated medium
    from dataclasses import asdict

    from sim.materials import TRANSLUCENT

    assert meta["options"]["part_material"] == "white-plastic"
    assert meta["part_material"] == {"tag": "white-plastic", "medium": asdict(TRANSLUCENT["white-plastic"])}
    assert {"part", "table"} <= set(meta["regions"])
    assert meta["files"] == {"rig": "rig.toml", "part": "part.ply", "housing": "housing.toml", "identified_rig": None}
    for name in ("rig.toml", "part.ply", "housing.toml"):
        assert (twin / name).is_file()


def test_twin_build_finds_the_flat_table_and_its_rim(box_scan):
    """The scan's disc is flat, square to its axis, at the calibrated table plane, 55 mm in radius: the
    table step finds no offset, lean or tilt, and the radius where the line turns down the rim."""
    _, _, twin = box_scan
    table = json.loads((twin / "twin.json").read_text())["table"]
    fit = table["fit"]
    assert fit is not None, table["note"]
    assert abs(fit["offset_mm"]) < 0.05 and fit["tilt_deg"] < 0.05 and fit["lean_deg"] < 0.05
    assert table["radius_mm"] == pytest.approx(TABLE_RADIUS_MM, abs=0.5)
    assert "table_radius_mm = " in (twin / "rig.toml").read_text()


def test_twin_build_finds_the_boards_lines(box_scan):
    """Each given board's line (sheet ∩ board) is a found board's line within 0.05 mm and 0.1°."""
    from scheimpflug.calibration.instrument import calibration_sheet_model
    from scheimpflug.model.housing import load_housing

    _, _, twin = box_scan
    found = load_housing(twin / "housing.toml")
    assert len(found) == 2
    origin, e_s, e_h = calibration_sheet_model(CONFIG).sheet_frame()
    n_sheet = np.cross(e_s, e_h)
    n_sheet /= np.linalg.norm(n_sheet)
    for _, c, nm, _, _ in WALLS:
        nm = np.array(nm) / np.linalg.norm(nm)
        d = np.cross(n_sheet, nm)                       # the wall's line in the sheet
        d /= np.linalg.norm(d)
        best = max(found, key=lambda b: abs(b.length_dir @ d))
        assert abs(best.length_dir @ d) > np.cos(np.radians(0.1))
        # the found board's centre lies on the given wall's plane and on the sheet: on the line
        assert abs((best.centre_mm - np.array(c)) @ nm) < 0.05
        assert abs((best.centre_mm - origin) @ n_sheet) < 0.05


def test_part_model_stands_where_the_box_stood(box_scan):
    """part.ply, in the part frame, lies on the box's faces; watertight; its foot on the table (z = 0)."""
    import trimesh

    _, _, twin = box_scan
    part = trimesh.load(twin / "part.ply")
    assert part.is_watertight
    v = part.vertices
    assert abs(v[:, 2].min()) < 1e-6                    # closed on the table's plane
    # distance of each vertex from the box's surface (outside: to the box; inside: to the nearest face)
    outside = np.linalg.norm(np.maximum(np.maximum(BOX_LO - v, v - BOX_HI), 0.0), axis=1)
    inside = np.min(np.concatenate([v - BOX_LO, BOX_HI - v], axis=1), axis=1)
    dist = np.where(outside > 0, outside, inside)
    assert np.median(dist) < 0.05 and np.percentile(dist, 90) < 0.5, (np.median(dist), np.percentile(dist, 90))
    meta = json.loads((twin / "twin.json").read_text())
    assert meta["part"]["n_bodies"] == 1


def test_twin_build_resumes_without_redoing(box_scan, capsys):
    _, scan, twin = box_scan
    before = {p.name: p.stat().st_mtime_ns for p in twin.iterdir() if p.is_file() and p.name != "twin.json"}
    assert main(["twin", "build", str(scan), "--calibration", str(CONFIG), "--preset", "rpi-v2-binned", "--out",
                 str(twin), "--no-identify"]) == 0
    err = capsys.readouterr().err
    for step in ("rig", "regions", "housing", "part"):
        assert f"twin build: {step}: done before, inputs unchanged: skipped" in err
    assert before == {p.name: p.stat().st_mtime_ns for p in twin.iterdir() if p.is_file() and p.name != "twin.json"}


def test_render_twin_puts_the_stripe_where_the_scan_has_it(box_scan):
    """``render rotary --twin`` at two of the scan's angles: the part's stripe within 1.5 px RMS
    (issue 36's figure on the part) of the scan's own frames, each wall board's within 0.5 px."""
    from scheimpflug.io.frames import open_frame_folder
    from scheimpflug.reconstruct import extract_folder_stripes

    tmp, scan, twin = box_scan
    out = tmp / "again"
    assert main(["render", "rotary", "--twin", str(twin), "--angles-deg=0,45", "--truth-pixels", "none", "--out",
                 str(out), "--quiet"]) == 0
    man = json.loads((out / "manifest.json").read_text())
    assert [f["angle_deg"] for f in man["frames"]] == [0.0, 45.0] and man["stripe_along"] == "rows"
    assert man["scenario_params"]["part_material"] == "white-plastic"          # twin.json's part material
    meta = json.loads((twin / "twin.json").read_text())
    # the walls: the lines of each found board, 5 px in from its ends (beyond, the board's end face)
    ranges = [("part", *meta["regions"]["part"], 1.5)] + [
        (f["board"], f["lines_px"][0] + 5, f["lines_px"][1] - 5, 0.5) for f in meta["housing"]["boards"]]
    a = extract_folder_stripes(open_frame_folder(scan), "cog")
    b = extract_folder_stripes(open_frame_folder(out), "cog")
    for name, lo, hi, limit in ranges:
        d = []
        for i in range(2):
            common, ia, ib = np.intersect1d(a.rows[i], b.rows[i], return_indices=True)
            k = (common >= lo) & (common <= hi)
            d.append(b.u[i][ib][k] - a.u[i][ia][k])
        d = np.concatenate(d)
        assert len(d) > 50 and np.sqrt(np.mean(d ** 2)) < limit, (name, len(d), np.sqrt(np.mean(d ** 2)))


def test_bad_input_one_error_each(box_scan, tmp_path, capsys):
    tmp, scan, twin = box_scan
    # --twin beside the options it replaces
    assert main(["render", "rotary", "--twin", str(twin), "--part", "sphere", "--out", str(tmp_path / "x")]) \
        == EXIT_ERROR
    assert "--twin gives the rig, the part and the housing: not with --part" in capsys.readouterr().err
    # explicit angles and a step at once
    assert main(["render", "rotary", "--twin", str(twin), "--angles-deg=0,45", "--step-deg", "10", "--out",
                 str(tmp_path / "z")]) == EXIT_ERROR
    assert "--angles-deg and --step-deg: give one" in capsys.readouterr().err
    # a twin folder of another format
    old = tmp_path / "old"
    old.mkdir()
    (old / "twin.json").write_text(json.dumps({"format": "scheimpflug-twin/0", "complete": True}))
    assert main(["render", "rotary", "--twin", str(old), "--out", str(tmp_path / "y")]) == EXIT_ERROR
    assert "build the twin again" in capsys.readouterr().err
    assert main(["twin", "build", str(scan), "--calibration", str(CONFIG), "--out", str(old), "--no-identify"]) \
        == EXIT_ERROR
    assert "another version of this program" in capsys.readouterr().err
    # a scan without angles
    noangle = tmp_path / "noangle"
    noangle.mkdir()
    (noangle / "frames").symlink_to(scan / "frames")
    man = json.loads((scan / "manifest.json").read_text())
    man["frames"][3].pop("angle_deg")
    (noangle / "manifest.json").write_text(json.dumps(man))
    assert main(["twin", "build", str(noangle), "--calibration", str(CONFIG), "--out", str(tmp_path / "t1"),
                 "--no-identify"]) == EXIT_ERROR
    assert "has no 'angle_deg': not a rotary scan" in capsys.readouterr().err
    assert not (tmp_path / "t1").exists()
    # an unknown inference backend: refused before anything is made
    assert main(["twin", "build", str(scan), "--calibration", str(CONFIG), "--out", str(tmp_path / "t3"),
                 "--inference", "torch+hand"]) == EXIT_ERROR
    assert "--inference: inference backend 'torch+hand' is not known" in capsys.readouterr().err
    assert not (tmp_path / "t3").exists()
    # an unreadable calibration
    bad = tmp_path / "bad.json"
    bad.write_text("{")
    assert main(["twin", "build", str(scan), "--calibration", str(bad), "--out", str(tmp_path / "t2"),
                 "--no-identify"]) == EXIT_ERROR
    assert not (tmp_path / "t2").exists()
    capsys.readouterr()
    # the twin folder of another scan
    assert main(["twin", "build", str(noangle), "--calibration", str(CONFIG), "--out", str(twin),
                 "--no-identify"]) == EXIT_ERROR
    assert "not a rotary scan" in capsys.readouterr().err
    other = tmp_path / "other"
    other.mkdir()
    (other / "frames").symlink_to(scan / "frames")
    man = json.loads((scan / "manifest.json").read_text())
    man["note"] = "another scan"
    (other / "manifest.json").write_text(json.dumps(man))
    assert main(["twin", "build", str(other), "--calibration", str(CONFIG), "--out", str(twin),
                 "--no-identify"]) == EXIT_ERROR
    assert "made from another scan or calibration" in capsys.readouterr().err
