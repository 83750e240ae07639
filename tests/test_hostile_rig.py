"""Hostile rig files and the design command (issue 12 item 9 and the rig tracebacks)."""

import dataclasses
import json
import math
import re
from importlib import resources

import numpy as np
import pytest

from scheimpflug.app.cli import main
from scheimpflug.app.commands._common import finite_json
from scheimpflug.errors import RigError
from scheimpflug.model.design import design_report
from scheimpflug.model.rig import _TABLES, KEY_RANGES, load_preset, rig_from_dict


def _fails(args, capsys, *needles):
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for n in needles:
        assert n in err, err
    return err


def _rig_file(tmp_path, text, name="rig.toml"):
    p = tmp_path / name
    p.write_text(text)
    return str(p)


@pytest.mark.parametrize("table, key, value, shown", [
    ("lens", "focal_length_mm", "1e-300", "1e-300"),
    ("sensor", "pixel_pitch_um", "1e-300", "1e-300"),
    ("sensor", "pixel_pitch_um", "5e-324", "5e-324"),          # was ZeroDivisionError in hinge.py
    ("laser", "tan_phi", "-1e300", "-1e+300"),
    ("sensor", "columns", "1" + "0" * 300, "characters"),       # a 300-digit integer: was OverflowError
    ("sensor", "rows", "1" + "0" * 300, "characters"),
    ("lens", "focal_length_mm", "1" + "0" * 300, "1e+300"),
    ("lens", "focal_length_mm", "1" + "0" * 400, "characters"),  # beyond any float
    ("sensor", "hinge_column", "1" + "0" * 400, "characters"),
    ("stage", "d0_mm", "-1" + "0" * 400, "characters"),
    ("sensor", "columns", "10000000", "10000000"),               # was an OpenCV failure in render
    ("lens", "f_number", "1e-300", "1e-300"),
    ("sensor", "exposure_ms", "1e300", "1e+300"),
])
def test_absurd_rig_values_are_one_line_naming_key_and_range(tmp_path, capsys, table, key, value, shown):
    rig = _rig_file(tmp_path, f"[{table}]\n{key} = {value}\n")
    err = _fails(["design", "--rig", rig, "--json"], capsys, f"[{table}] {key} = ", shown,
                 KEY_RANGES[table][key])
    assert len(err) < 300                            # a 300-digit number is not echoed in full
    assert capsys.readouterr().out == ""


@pytest.mark.parametrize("toml", ["[lens]\nf_number = 1e-300\n", "[sensor]\nexposure_ms = 1e300\n",
                                  "[sensor]\ncolumns = 10000000\n"])
def test_render_refuses_them_before_rendering(tmp_path, capsys, toml):
    out = tmp_path / "o"
    _fails(["render", "blocker", "--rig", _rig_file(tmp_path, toml), "--binning", "8", "--out", str(out)],
           capsys, "out of range")
    assert not out.exists()


def test_sensor_tilt_near_90_degrees_is_refused(tmp_path, capsys):
    """d − f·tan φ > 0 but tiny: β → 90°, the sensor along the optical axis."""
    rig = _rig_file(tmp_path, "[laser]\nscheimpflug_distance_mm = 150\ntan_phi = 2.7272\n")
    _fails(["design", "--rig", rig], capsys, "sensor tilt", "at most 85")


def test_d0_zero_works(tmp_path, capsys):
    """d0 = 0 (the stage zero at the object hinge) is natural: finite numbers, null where undefined."""
    rig = _rig_file(tmp_path, "[stage]\nd0_mm = 0\n")
    assert main(["design", "--rig", rig, "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["stage_zero_column_px"] is None and d["focal_length_check_mm"] is None
    assert d["stage_range_mm"] == pytest.approx(d["distance_range_mm"])      # s = D when d0 = 0
    assert main(["design", "--rig", rig]) == 0
    text = capsys.readouterr().out
    assert "–" in text and "nan" not in text.lower() and "inf" not in text.replace("info", "")


def test_json_never_holds_inf_or_nan():
    obj = {"a": math.inf, "b": [1.0, -math.inf, {"c": math.nan}], "d": np.float64("nan"),
           "e": np.array([1.0, np.inf]), "f": 2, "g": "x"}
    clean = finite_json(obj)
    assert clean == {"a": None, "b": [1.0, None, {"c": None}], "d": None, "e": [1.0, None], "f": 2,
                     "g": "x"}
    json.dumps(clean, allow_nan=False)


def test_every_rig_key_has_a_documented_range():
    """Ranges live in one table, are documented beside each key (docstring and paper.toml)."""
    toml = resources.files("scheimpflug.model").joinpath("presets", "paper.toml").read_text("utf-8")
    for table, cls in _TABLES.items():
        names = [f.name for f in dataclasses.fields(cls)]
        assert sorted(KEY_RANGES[table]) == sorted(names), table
        doc = " ".join(cls.__doc__.split())
        for key in names:
            rng = KEY_RANGES[table][key]
            assert rng in doc, (table, key, rng)
            line = re.search(rf"^{key} = .*$", toml, re.M).group(0)
            assert f"range {rng}" in line, line


def test_design_is_finite_at_the_corners_of_the_ranges():
    """Computations cannot overflow for values inside the ranges: extreme but valid rigs."""
    corners = [
        {"lens": {"focal_length_mm": 0.5}, "laser": {"scheimpflug_distance_mm": 1e5, "tan_phi": -100}},
        {"lens": {"focal_length_mm": 5000}, "laser": {"scheimpflug_distance_mm": 1e5, "tan_phi": 0.0},
         "sensor": {"pixel_pitch_um": 0.1, "hinge_column": 1e7}},
        {"lens": {"focal_length_mm": 5000}, "laser": {"scheimpflug_distance_mm": 1e5, "tan_phi": 19.0},
         "sensor": {"pixel_pitch_um": 1000, "columns": 1, "rows": 65535, "hinge_column": 0.6,
                    "axis_row": -1e7}, "stage": {"d0_mm": 1e6, "axis_mm": -1e6}},
        {"stage": {"d0_mm": 0.0, "axis_mm": 0.0}},
    ]
    paper = {"d0_mm": -466.0, "axis_mm": 179.45, "calibration_table_z_mm": -54.0,
             "calibration_plate_height_mm": 89.0, "rotary_table_z_mm": -70.0}
    for tables in corners:      # derived keys given: derived, they can leave their ranges (refused)
        tables.setdefault("sensor", {})["exposure_ms"] = 0.5
        tables.setdefault("laser", {})["waist_distance_mm"] = 640.0
        tables["stage"] = {**paper, **tables.get("stage", {})}
        rep = design_report(rig_from_dict(tables))
        flat = json.dumps(finite_json(rep))
        values = [v for v in re.findall(r"-?\d[\d.e+-]*", flat)]
        assert values and all(math.isfinite(float(v)) for v in values)
        assert rep["tilt_deg"] <= 85.0 and math.isfinite(rep["F2_px_mm"]) and math.isfinite(rep["C_mm"])


def test_rig_range_errors_are_rig_errors():
    with pytest.raises(RigError, match=r"\[sensor\] adc_bits = 17: out of range: must be in \[1, 16\]"):
        load_preset("paper").replace(sensor={"adc_bits": 17})


def test_a_derived_key_out_of_its_range_is_one_line(tmp_path, capsys):
    """A 65 m tall sensor (65535 rows of 1 mm) derives a 63 m calibration plate: refused, the key named."""
    rig = _rig_file(tmp_path, "[lens]\nfocal_length_mm = 5000\n[laser]\nscheimpflug_distance_mm = 1e5\n"
                              "tan_phi = 19.0\n[sensor]\npixel_pitch_um = 1000\ncolumns = 1\nrows = 65535\n"
                              "hinge_column = 0.6\naxis_row = -1e7\nexposure_ms = 0.5\n")
    _fails(["design", "--rig", rig, "--json"], capsys, "out of range", "derived from the other keys")
