"""The camera chain in the frame folder: twin frames written as the camera writes them, read by ``import``.

A tiny binned rotary render with the Raspberry Pi camera's chain → RGB JPEG files in
``frames/`` → ``scheimpflug import`` (the real frames' path: ``--channel r``, angles) →
``reconstruct`` with the rig's closed-form calibration → points on the part.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from scheimpflug.app.cli import main
from scheimpflug.calibration import Calibration

pytestmark = pytest.mark.render


def _rig_file(tmp_path, chain: str) -> str:
    path = tmp_path / "rig.toml"
    path.write_text("[laser]\nwavelength_nm = 650.0\n\n[chain]\n" + chain)
    return str(path)


def _calibration(folder, out) -> str:
    truth = json.loads((folder / "truth" / "rig_truth.json").read_text())
    rig = json.loads((folder / "manifest.json").read_text())["rig"]["sensor"]
    Calibration(hinge_u_px=truth["hinge_u_px"], hinge_v_px=truth["hinge_v_px"], F2_px_mm=truth["F2_px_mm"],
                F2_sigma_px_mm=0.0, d0_mm=truth["d0_mm"], C_mm=truth["C_mm"], C_sigma_mm=0.0,
                endpoint_fit_r2=(1.0, 1.0), method="paper", columns=rig["columns"], rows=rig["rows"]).save(out)
    return str(out)


def test_twin_jpeg_frames_import_and_reconstruct_like_real_ones(tmp_path, capsys):
    rig = _rig_file(tmp_path, 'preset = "raspberry_pi_v2"\nbayer_pattern = "RGGB"\n')
    twin = tmp_path / "twin"
    assert main(["render", "rotary", "--rig", rig, "--part", "cylinder", "--step-deg", "90", "--frames", "3",
                 "--binning", "8", "--quiet", "--out", str(twin)]) == 0
    m = json.loads((twin / "manifest.json").read_text())
    files = [twin / f["file"] for f in m["frames"]]
    assert [f.suffix for f in files] == [".jpg"] * 3 and all(f.is_file() for f in files)
    from PIL import Image

    with Image.open(files[0]) as im:
        assert (im.format, im.mode, im.size) == ("JPEG", "RGB", (m["rig"]["sensor"]["columns"],
                                                                  m["rig"]["sensor"]["rows"]))
        rgb = np.asarray(im)
    red, green = rgb[..., 0].astype(float).sum(), rgb[..., 1].astype(float).sum()
    assert red > 3 * green > 0                      # a red laser lands on the R pixels (QE 0.45 against 0.06)
    # the same run again: the same bytes (same seed, same files)
    again = tmp_path / "again"
    assert main(["render", "rotary", "--rig", rig, "--part", "cylinder", "--step-deg", "90", "--frames", "3",
                 "--binning", "8", "--quiet", "--out", str(again)]) == 0
    assert all(f.read_bytes() == (again / "frames" / f.name).read_bytes() for f in files)   # exact: same run

    imported = tmp_path / "imported"
    assert main(["import", *map(str, files), "--channel", "r", "--angles-deg", "0:90", "--stripe-along",
                 "columns", "--quiet", "--out", str(imported)]) == 0
    cloud = tmp_path / "cloud.ply"
    assert main(["reconstruct", str(imported), "--calibration", _calibration(twin, tmp_path / "cal.json"),
                 "--axis-mm", str(m["rig"]["stage"]["axis_mm"]), "--out", str(cloud), "--json", "--quiet"]) == 0
    out = capsys.readouterr().out
    report = json.loads(out[out.index("{"):])
    assert report["n_points"] > 200, report
    assert main(["evaluate", str(cloud), "--mesh", str(twin / "truth" / "mesh.ply"), "--json"]) == 0
    out = capsys.readouterr().out
    score = json.loads(out[out.index("{"):])
    # on the part: 0.47 mm RMS here, against 0.07 mm for the grey 16-bit frames of the same render —
    # at 8 × binning the stripe is ≈ 1 px wide and its red light is sampled on every other column only
    assert score["n_points"] == report["n_points"] and score["rms_mm"] < 1.0, score


def test_the_flood_light_takes_its_own_channel_responses(tmp_path):
    """With a camera pass the laser's and the flood light are apart: each gets its channels' QE."""
    import cv2

    rig = tmp_path / "rig.toml"
    rig.write_text('[laser]\nwavelength_nm = 650.0\n[environment]\nflood_irradiance_w_m2 = 5.0\n[twin]\n'
                   'camera_spp = 1\n[chain]\nformat = "png8"\nlaser_qe_r = 0.5\nlaser_qe_g = 0.05\n'
                   'laser_qe_b = 0.05\nflood_qe_r = 0.2\nflood_qe_g = 0.4\nflood_qe_b = 0.2\n')
    assert main(["render", "rotary", "--rig", str(rig), "--part", "cylinder", "--step-deg", "90", "--frames", "1",
                 "--binning", "16", "--quiet", "--out", str(tmp_path / "f")]) == 0
    rgb = cv2.imread(str(tmp_path / "f" / "frames" / "00000.png"))[..., ::-1].astype(float)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    flood = (g > 8) & (r < 2 * g)                  # flood-lit, away from the red stripe
    assert flood.sum() > 500
    # linear tone: G/R = 0.4/0.2 and B/R = 0.2/0.2 where the flood light dominates (with the
    # laser's responses it would be 0.1); low codes' rounding and noise spread the ratios
    assert 1.6 < np.median(g[flood] / np.maximum(r[flood], 1)) < 2.6
    assert 0.8 < np.median(b[flood] / np.maximum(r[flood], 1)) < 1.25
