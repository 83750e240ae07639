"""Rig file validation, the design command's outputs, and the inverse design."""

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from scheimpflug.app.cli import main
from scheimpflug.errors import RigError
from scheimpflug.model.design import design_report, inverse_design
from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.rig import (
    DERIVED_KEYS,
    DERIVED_STAGE_KEYS,
    load_preset,
    load_rig,
    rig_from_dict,
    rig_to_dict,
    rig_to_toml,
)

BAD = [
    ({"lens": {"focal_length_mm": 0.0}}, "focal_length_mm"),
    ({"lens": {"focal_length_mm": -5.0}}, "focal_length_mm"),
    ({"laser": {"scheimpflug_distance_mm": 10.0, "tan_phi": 0.5}}, "tan_phi"),  # d − f tan φ < 0
    ({"sensor": {"hinge_column": 600.0}}, "hinge_column"),  # hinge inside the sensor
    ({"sensor": {"hinge_column": 1215.2}}, "hinge_column"),  # straddles the last pixel
    ({"sensor": {"pixel_pitch_um": 0.0}}, "pixel_pitch_um"),
    ({"sensor": {"columns": 0}}, "columns"),
    ({"sensor": {"rows": -3}}, "rows"),
    ({"lens": {"f_number": float("nan")}}, "f_number"),
    ({"laser": {"tan_phi": float("inf")}}, "tan_phi"),
    ({"lens": {"focal_lenght_mm": 50.0}}, "focal_lenght_mm"),
    ({"optics": {}}, "optics"),
    ({"lens": {"focal_length_mm": "55"}}, "focal_length_mm"),
    ({"sensor": {"columns": 1216.5}}, "columns"),
    ({"sensor": {"columns": True}}, "columns"),
    ({"laser": {"divergence_mrad": 0.1}}, "divergence_mrad"),  # below the diffraction limit
]


@pytest.mark.parametrize("data,key", BAD)
def test_impossible_rigs_name_the_key(data, key):
    with pytest.raises(RigError, match=key):
        rig_from_dict(data)


def test_rig_file_round_trip(tmp_path, paper_rig):
    path = tmp_path / "rig.toml"
    path.write_text(rig_to_toml(paper_rig))
    assert load_rig(path) == paper_rig


@pytest.mark.parametrize("text,msg", [("[lens\nfocal", "not valid TOML"), ("", None)])
def test_rig_file_errors(tmp_path, text, msg):
    path = tmp_path / "rig.toml"
    path.write_text(text)
    if msg is None:  # an empty file: the paper's geometry; stages, laser waist and exposure derived
        rig, paper = load_rig(path), load_preset("paper")
        derived = {"laser": ("waist_distance_mm",), "sensor": ("exposure_ms",), "stage": DERIVED_STAGE_KEYS}
        for table in ("lens", "laser", "sensor", "stage", "environment"):
            a, b = rig_to_dict(rig)[table], rig_to_dict(paper)[table]
            assert {k: v for k, v in a.items() if k not in derived.get(table, ())} == \
                   {k: v for k, v in b.items() if k not in derived.get(table, ())}
        assert rig.derived == DERIVED_KEYS and paper.derived == ()
    else:
        with pytest.raises(RigError, match=msg):
            load_rig(path)
    with pytest.raises(RigError, match="does not exist"):
        load_rig(tmp_path / "missing.toml")


def test_cli_prints_one_line_error_and_exits_nonzero(tmp_path, capsys):
    path = tmp_path / "rig.toml"
    path.write_text("[lens]\nfocal_length_mm = -1\n")
    assert main(["design", "--rig", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "focal_length_mm" in err[0]


def test_design_json_paper(capsys):
    assert main(["design", "--preset", "paper", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    for key in ("tilt_deg", "tan_beta", "hinge_px", "F2_px_mm", "C_mm", "distance_range_mm",
                "distance_resolution_center_mm", "height_range_near_mm", "height_range_far_mm"):
        assert key in out
    assert out["hinge_px"] == [3196.0, 771.0]


def test_design_json_other_rig(tmp_path, capsys):
    """A 35 mm lens, 3.45 µm pitch, 2448 × 2048 sensor: values from the formulas computed here."""
    f, d, t, p, nu, nv, uh, vh = 35.0, 100.0, 0.1, 3.45e-3, 2448, 2048, 5000.0, 1000.0
    path = tmp_path / "rig.toml"
    path.write_text(f"[lens]\nfocal_length_mm = {f}\n[laser]\nscheimpflug_distance_mm = {d}\ntan_phi = {t}\n"
                    f"[sensor]\npixel_pitch_um = 3.45\ncolumns = {nu}\nrows = {nv}\nhinge_column = {uh}\n"
                    f"axis_row = {vh}\n")
    assert main(["design", "--rig", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    beta = math.atan(f / (d - f * t))
    F2 = -f * f / (p * math.cos(math.atan(t)) * math.sin(beta))
    C = f / math.sin(beta)
    assert out["tilt_deg"] == pytest.approx(math.degrees(beta), rel=1e-12)
    assert out["F2_px_mm"] == pytest.approx(F2, rel=1e-12)
    assert out["C_mm"] == pytest.approx(C, rel=1e-12)
    assert out["distance_range_mm"] == pytest.approx([F2 / -uh, F2 / (nu - 1 - uh)], rel=1e-12)
    assert out["distance_resolution_center_mm"] == pytest.approx(-F2 / (nu // 2 - uh) ** 2, rel=1e-12)
    assert out["height_range_near_mm"] == pytest.approx(C * nv / (uh + 0.5), rel=1e-12)
    assert out["height_range_far_mm"] == pytest.approx(C * nv / (uh - nu + 0.5), rel=1e-12)


def test_design_table_and_plot(tmp_path, capsys):
    png = tmp_path / "d.png"
    assert main(["design", "--plot", str(png)]) == 0
    text = capsys.readouterr().out
    assert "Eq. 5" in text and "mm/px" in text and "21.6462" in text
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("kw", [{"tan_phi": 0.2075}, {"scheimpflug_distance_mm": 150.0}, {"tan_phi": 0.4}])
def test_inverse_design_covers_the_wanted_range(kw):
    near, far = 503.0, 777.0
    c = inverse_design(55.0, 5.86, 1216, near, far, **kw)
    rig = rig_from_dict({"laser": {"tan_phi": c.tan_phi, "scheimpflug_distance_mm": c.scheimpflug_distance_mm},
                         "sensor": {"hinge_column": c.hinge_column}})
    g = hinge_geometry(rig)
    offset = 55.0 * math.hypot(1.0, c.tan_phi)  # hinge to Scheimpflug line along the sheet, f/cos φ
    np.testing.assert_allclose(g.distance_from_column([0.0, 1215.0]) + offset, [near, far], rtol=1e-10)
    assert math.isclose(math.tan(math.radians(c.tilt_deg)),
                        55.0 / (c.scheimpflug_distance_mm - 55.0 * c.tan_phi), rel_tol=1e-10)


def test_inverse_design_impossible_range():
    with pytest.raises(RigError, match="sin β"):
        inverse_design(55.0, 5.86, 1216, 60.0, 5000.0, tan_phi=0.2)
    with pytest.raises(RigError, match="baselines that work: d = "):
        inverse_design(55.0, 5.86, 1216, 450.0, 900.0, scheimpflug_distance_mm=150.0)


def test_inverse_design_cli_writes_a_rig(tmp_path, capsys):
    out = tmp_path / "new.toml"
    assert main(["design", "--near-mm", "500", "--far-mm", "850", "--write-rig", str(out), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    again = design_report(load_rig(out))
    for key in ("tilt_deg", "F2_px_mm", "C_mm", "depth_range_mm"):
        assert again[key] == pytest.approx(rep[key], rel=1e-12)
    offset = 55.0 * math.hypot(1.0, 0.2075)
    assert np.add(rep["distance_range_mm"], offset) == pytest.approx([500.0, 850.0], rel=1e-10)


def test_python_dash_m_entry_point():
    r = subprocess.run([sys.executable, "-m", "scheimpflug", "design", "--json"], capture_output=True, text=True)
    assert r.returncode == 0 and json.loads(r.stdout)["C_mm"] == pytest.approx(149.1023, rel=1e-6)
