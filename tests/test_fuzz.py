"""Property-based fuzzing of the command line (issue 12): never a traceback, never a silent NaN.

Every property runs the real ``scheimpflug`` entry point (:func:`scheimpflug.app.cli.main`) in
process on generated input and asserts the contract of docs/reference/interface.md: exit status 0 with finite
numbers where numbers are promised, or exit status 2 with exactly one error line on stderr.  An
unexpected exception ends in the CLI's last-resort handler (exit status 70, "internal error …
please report"), which these tests count as a failure.

* random rig tables → ``design --json``;
* random frame folders (mutations of a valid binned calibration folder: missing keys, wrong
  types, NaN/inf/huge numbers, truncated, garbage, colour, wrong-size, 8-bit or saturated PNGs,
  duplicates, missing files, flipped frames) and calibration files → ``calibrate``, ``axis``
  and ``reconstruct``;
* random point clouds and meshes (NaN/inf/huge coordinates, bad face indices, degenerate
  triangles, truncated files, PLY/STL/OBJ) → ``evaluate``.

Determinism and budget: ``derandomize=True`` (Hypothesis derives its examples from the test's
source, no random seed, no example database), so CI runs the same examples every time.  Example
counts are set so the whole file takes ≈ 40 s on the 2-core machine (≤ 60 s; the counts are in
``BUDGET``).  To search harder locally: ``SCHEIMPFLUG_FUZZ_SCALE=10 pytest tests/test_fuzz.py``
(and ``SCHEIMPFLUG_DEBUG=1`` to see the traceback of what it finds).
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import shutil
import tempfile
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from synth_frames import Camera, PlateScene, calibration_folder, plate_frame, rig_dict, write_folder
from test_hostile_calibration import GEO, STAGES

from scheimpflug.app.cli import EXIT_ERROR, main
from scheimpflug.calibration import calibrate_folder
from scheimpflug.model.rig import _TABLES, KEY_RANGES

SCALE = float(os.environ.get("SCHEIMPFLUG_FUZZ_SCALE", "1"))
BUDGET = {"design": 150, "folders": 40, "calibration_files": 30, "evaluate": 60}
"""Examples per property (× SCHEIMPFLUG_FUZZ_SCALE)."""


def _settings(name: str):
    return settings(max_examples=max(1, int(BUDGET[name] * SCALE)), deadline=None, derandomize=True,
                    database=None, print_blob=True,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.filter_too_much])


def _run(args: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        status = main(args)
    OUTCOMES.setdefault(args[0], []).append(status)
    return status, out.getvalue(), err.getvalue()


OUTCOMES: dict[str, list[int]] = {}
"""Exit status of every run, per command (to see what the examples reach)."""


def _check_contract(args, status, out, err) -> None:
    """Exit 0, or exit 2 with one error line; never a traceback or an internal error."""
    assert status in (0, EXIT_ERROR), f"{args}: exit {status}\n{err}"
    assert "Traceback" not in err, f"{args}\n{err}"
    if status == EXIT_ERROR:
        errors = [line for line in err.splitlines() if not line.startswith("warning")]
        errors = [line for line in errors if not line.startswith(("calibrate ", "extract "))]  # bars
        assert len(errors) == 1 and ": error: " in errors[0], f"{args}\n{err}"


def _finite_numbers(d: dict, keys) -> None:
    for k in keys:
        values = d[k] if isinstance(d[k], list) else [d[k]]
        assert all(isinstance(v, (int, float)) and math.isfinite(v) for v in values), (k, d[k])


# ------------------------------------------------------------------ values from the whole range

HOSTILE_NUMBERS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, allow_subnormal=True),
    st.integers(min_value=-(10 ** 400), max_value=10 ** 400),
    st.sampled_from([0, -0.0, 5e-324, 1e-300, 1e300, -1e300, 2 ** 63, 10 ** 300, math.inf, math.nan]),
)
WRONG_TYPES = st.one_of(st.booleans(), st.text(max_size=6), st.lists(st.integers(0, 3), max_size=2),
                        st.builds(dict), st.none())


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{}"
    return '""'   # None: TOML has no null; an empty string is as wrong


@st.composite
def rig_tables(draw):
    """Any subset of keys; values near the paper rig, from the whole float range, or of wrong types."""
    from scheimpflug.model.rig import load_preset, rig_to_dict

    base = rig_to_dict(load_preset("paper"))
    tables = {}
    for table in draw(st.lists(st.sampled_from(sorted(_TABLES) + ["bogus"]), max_size=4, unique=True)):
        keys = sorted(KEY_RANGES.get(table, {"x": ""})) + ["unknown_key"]
        chosen = draw(st.lists(st.sampled_from(keys), max_size=5, unique=True))
        values = {}
        for key in chosen:
            default = base.get(table, {}).get(key, 1.0)
            kind = draw(st.integers(0, 9))
            if kind < 5 and isinstance(default, (bool, str)):   # [twin] switches: as they are
                v = default
            elif kind < 5:        # plausible: the default scaled (most examples pass validation)
                v = default * draw(st.floats(0.3, 3.0)) if isinstance(default, float) else \
                    max(1, int(default * draw(st.floats(0.3, 2.0))))
            elif kind < 8:
                v = draw(HOSTILE_NUMBERS)
            else:
                v = draw(WRONG_TYPES)
            values[key] = v
        tables[table] = values
    return tables


def _toml(tables: dict) -> str:
    lines = []
    for table, values in tables.items():
        lines.append(f"[{table}]")
        lines += [f"{k} = {_toml_value(v)}" for k, v in values.items()]
    return "\n".join(lines) + "\n"


DESIGN_FIELDS = ("tilt_deg", "tan_beta", "hinge_px", "F2_px_mm", "C_mm", "distance_range_mm",
                 "distance_resolution_center_mm", "height_range_near_mm", "height_range_far_mm")


@_settings("design")
@given(tables=rig_tables(), text=st.booleans())
def test_fuzz_design_with_random_rig_tables(tables, text):
    with tempfile.TemporaryDirectory() as tmp:
        rig = Path(tmp) / "rig.toml"
        rig.write_text(_toml(tables))
        args = ["design", "--rig", str(rig)] + ([] if text else ["--json"])
        status, out, err = _run(args)
    _check_contract(args, status, out, err)
    if status == 0 and not text:
        d = json.loads(out)
        _finite_numbers(d, DESIGN_FIELDS)
        assert d["C_mm"] > 0 and d["F2_px_mm"] < 0 and 0 < d["tilt_deg"] <= 85


# ------------------------------------------------------------------ frame folders


@pytest.fixture(scope="module")
def base_folder(tmp_path_factory):
    """Valid binned folders to mutate — a calibration (10 plate frames) and a blocker (3 frames of one
    face, angle 0) — and the calibration file of the first."""
    root = tmp_path_factory.mktemp("fuzzbase")
    path, _ = calibration_folder(root / "cal", GEO, stages=STAGES, seed=3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        calibrate_folder(path).best.save(root / "cal.json")
    rng = np.random.default_rng(5)
    face = [plate_frame(GEO, 150.0, PlateScene(bottom_mm=-70.0, height_mm=140.0), Camera(), rng)[0]
            for _ in range(3)]
    blocker = write_folder(root / "blk", face, [{"angle_deg": 0.0}] * 3, scenario="blocker",
                           rig=rig_dict(GEO), scenario_params={"blocker_thickness_mm": 2.0})
    return {"calibration": path, "blocker": blocker}, root / "cal.json"


MANIFEST_PATHS = [("scenario",), ("scenario_params",), ("scenario_params", "plate_height_mm"),
                  ("scenario_params", "blocker_thickness_mm"), ("rig",), ("rig", "sensor"),
                  ("rig", "sensor", "rows"), ("rig", "sensor", "columns"), ("rig", "sensor", "adc_bits"),
                  ("rig", "lens"), ("rig", "lens", "focal_length_mm"), ("rig", "sensor", "pixel_pitch_um"),
                  ("adc_bits",),
                  ("frames",), ("frames", 0), ("frames", 0, "file"), ("frames", 3, "stage_mm"),
                  ("frames", 5, "stage_mm"), ("frames", 2, "angle_deg"), ("frames", 1, "seed"),
                  ("frames", 4, "exposure_ms")]
FRAME_DAMAGE = ["truncate", "garbage", "delete", "colour", "wrong_size", "eight_bit", "saturate",
                "blank", "flip", "sixteen_bit_scaled"]


def _set(m, path, value, delete):
    node = m
    for k in path[:-1]:
        if isinstance(node, dict) and k in node or isinstance(node, list) and isinstance(k, int) \
                and k < len(node):
            node = node[k]
        else:
            return
    k = path[-1]
    if isinstance(node, dict):
        node.pop(k, None) if delete else node.__setitem__(k, value)
    elif isinstance(node, list) and isinstance(k, int) and k < len(node):
        node.pop(k) if delete else node.__setitem__(k, value)


def _damage(png: Path, how: str, data) -> None:
    if not png.exists():
        return
    img = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
    if img is None or img.ndim != 2:                  # damaged already
        how = "garbage" if how not in ("truncate", "delete") else how
    if how == "truncate":
        os.truncate(png, data.draw(st.integers(0, max(0, png.stat().st_size - 1))))
    elif how == "garbage":
        png.write_bytes(data.draw(st.binary(max_size=64)))
    elif how == "delete":
        png.unlink()
    elif how == "colour":
        cv2.imwrite(str(png), cv2.merge([img, img, img]))
    elif how == "wrong_size":
        cv2.imwrite(str(png), img[: data.draw(st.integers(1, img.shape[0])), : data.draw(st.integers(1, 40))])
    elif how == "eight_bit":
        cv2.imwrite(str(png), (img >> 4).astype(np.uint8))
    elif how == "saturate":
        top = np.iinfo(img.dtype).max
        cv2.imwrite(str(png), np.full_like(img, data.draw(st.sampled_from([min(4095, top), top]))))
    elif how == "blank":
        cv2.imwrite(str(png), np.zeros_like(img))
    elif how == "flip":
        cv2.imwrite(str(png), cv2.flip(img, 1))
    else:
        cv2.imwrite(str(png), (img.astype(np.uint32) << 4).astype(np.uint16))


def _mutated_folder(data, bases: dict, dst: Path) -> Path:
    base = bases[data.draw(st.sampled_from(sorted(bases)))]
    shutil.copytree(base, dst)
    n_frames = len(list((dst / "frames").glob("*.png")))
    m = json.loads((dst / "manifest.json").read_text())
    for _ in range(data.draw(st.integers(0, 3))):
        path = data.draw(st.sampled_from(MANIFEST_PATHS))
        if data.draw(st.booleans()):
            _set(m, path, None, delete=True)
        else:
            _set(m, path, data.draw(st.one_of(HOSTILE_NUMBERS, WRONG_TYPES)), delete=False)
    if data.draw(st.booleans()) and isinstance(m.get("frames"), list) and m["frames"]:
        m["frames"].append(dict(m["frames"][0]) if isinstance(m["frames"][0], dict) else 0)  # a duplicate
    scenario = data.draw(st.sampled_from(["keep", "keep", "blocker", "rotary", "none"]))
    if scenario != "keep":
        m.pop("scenario", None) if scenario == "none" else m.__setitem__("scenario", scenario)
    if scenario in ("blocker", "rotary") and isinstance(m.get("frames"), list):
        for f in m["frames"]:
            if isinstance(f, dict):
                f.pop("stage_mm", None)
                f["angle_deg"] = float(data.draw(st.sampled_from([0.0, 10.0, 45.0, 90.0])))
    (dst / "manifest.json").write_text(json.dumps(m))
    for _ in range(data.draw(st.integers(0, 3))):
        i = data.draw(st.integers(0, n_frames - 1))
        _damage(dst / "frames" / f"{i:05d}.png", data.draw(st.sampled_from(FRAME_DAMAGE)), data)
    return dst


@_settings("folders")
@given(data=st.data())
def test_fuzz_calibrate_axis_reconstruct_with_random_frame_folders(base_folder, data):
    base, cal = base_folder
    with tempfile.TemporaryDirectory() as tmp:
        folder = _mutated_folder(data, base, Path(tmp) / "f")
        cal_out, cloud = Path(tmp) / "c.json", Path(tmp) / "c.ply"
        model = data.draw(st.sampled_from(["auto", "paper", "general"]))
        runs = [["calibrate", str(folder), "--json", "--quiet", "--out", str(cal_out), "--model", model],
                ["axis", str(folder), "--calibration", str(cal), "--json"],
                ["reconstruct", str(folder), "--calibration", str(cal), "--axis-mm", "150", "--quiet",
                 "--json", "--out", str(cloud)]]
        for args in runs:
            status, out, err = _run(args)
            _check_contract(args, status, out, err)
            if status == 0 and args[0] == "calibrate":
                d = json.loads(out)
                _finite_numbers(d, ("hinge_px", "F2_px_mm", "d0_mm", "C_mm"))
                assert json.loads(cal_out.read_text())["F2_px_mm"] < 0
            if status == 0 and args[0] == "axis":
                _finite_numbers(json.loads(out), ("axis_mm",))
            if status == 0 and args[0] == "reconstruct":
                d = json.loads(out)
                assert d["n_points"] > 0 and cloud.exists()


CAL_FIELDS = ["hinge_px", "F2_px_mm", "F2_sigma_px_mm", "d0_mm", "C_mm", "C_sigma_mm", "endpoint_fit_r2",
              "columns", "rows", "plate_height_mm", "n_frames", "hinge_u_sigma_px", "method"]


@_settings("calibration_files")
@given(data=st.data())
def test_fuzz_axis_and_reconstruct_with_random_calibration_files(base_folder, data):
    base, cal = base_folder
    d = json.loads(cal.read_text())
    for _ in range(data.draw(st.integers(1, 3))):
        key = data.draw(st.sampled_from(CAL_FIELDS))
        if data.draw(st.booleans()):
            d.pop(key, None)
        elif key == "hinge_px" and data.draw(st.booleans()):
            d[key] = [data.draw(HOSTILE_NUMBERS), d.get("hinge_px", [0, 0])[1] if isinstance(
                d.get("hinge_px"), list) and len(d["hinge_px"]) > 1 else 0]
        else:
            d[key] = data.draw(st.one_of(HOSTILE_NUMBERS, WRONG_TYPES))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "cal.json"
        try:
            path.write_text(json.dumps(d))
        except (OverflowError, ValueError):
            path.write_text(repr(d))                       # not even JSON
        blk = Path(tmp) / "blk"
        shutil.copytree(base["blocker"], blk)
        for args in (["axis", str(blk), "--calibration", str(path), "--json"],
                     ["reconstruct", str(blk), "--calibration", str(path), "--axis-mm", "150", "--quiet",
                      "--out", str(Path(tmp) / "c.ply")]):
            status, out, err = _run(args)
            _check_contract(args, status, out, err)


# ------------------------------------------------------------------ clouds and meshes

PLAIN = st.floats(-60, 60)
COORD = st.one_of(PLAIN, PLAIN, PLAIN, PLAIN, PLAIN, PLAIN, st.floats(allow_nan=True, allow_infinity=True),
                  st.sampled_from([0.0, 1e300, -1e300, 5e-324]))   # mostly plain: the success path too


def _write_cloud(data, path: Path) -> None:
    n = data.draw(st.integers(0, 60))
    xyz = np.array(data.draw(st.lists(st.tuples(COORD, COORD, COORD), min_size=n, max_size=n)),
                   dtype=np.float64).reshape(-1, 3)
    kind = data.draw(st.sampled_from(["binary", "binary", "ascii", "ascii", "truncated", "header_only"]))
    if kind == "binary":
        from scheimpflug.io.ply import write_point_cloud
        from scheimpflug.reconstruct import PointCloud

        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            write_point_cloud(path, PointCloud(xyz, np.zeros(n), np.zeros(n, np.int64), np.zeros(n)))
        return
    head = f"ply\nformat ascii 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\n" \
           "end_header\n"
    body = "".join(f"{float(a)!r} {float(b)!r} {float(c)!r}\n" for a, b, c in xyz)
    text = head + ("" if kind == "header_only" else body)
    if kind == "truncated":
        text = text[: data.draw(st.integers(0, len(text)))]
    path.write_text(text)


def _write_mesh(data, path_stem: Path) -> Path:
    kind = data.draw(st.sampled_from(["box", "box", "cylinder", "cylinder", "random", "random", "folder",
                                      "missing"]))
    fmt = data.draw(st.sampled_from(["ply", "stl", "obj"]))
    path = path_stem.with_suffix("." + fmt)
    if kind == "folder":
        path.mkdir()
        return path
    if kind == "missing":
        return path
    if kind == "box":
        mesh = trimesh.creation.box(extents=(40.0, 40.0, 40.0))
    elif kind == "cylinder":
        mesh = trimesh.creation.cylinder(radius=data.draw(st.floats(0.1, 50)), height=20.0, sections=16)
    else:
        nv = data.draw(st.integers(0, 8))
        verts = np.array(data.draw(st.lists(st.tuples(COORD, COORD, COORD), min_size=nv, max_size=nv)),
                         dtype=np.float64).reshape(-1, 3)
        nf = data.draw(st.integers(0, 6))
        faces = np.array(data.draw(st.lists(st.tuples(*[st.integers(-1, nv + 1)] * 3), min_size=nf,
                                            max_size=nf)), dtype=np.int64).reshape(-1, 3)
        mesh = trimesh.Trimesh(verts, np.clip(faces, 0, max(nv - 1, 0)) if nv else faces, process=False)
    with contextlib.suppress(Exception), np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore")          # whatever trimesh cannot export is simply absent
        mesh.export(path)
    if path.exists() and data.draw(st.booleans()):
        os.truncate(path, data.draw(st.integers(0, path.stat().st_size)))
    return path


@_settings("evaluate")
@given(data=st.data())
def test_fuzz_evaluate_with_random_clouds_and_meshes(data):
    with tempfile.TemporaryDirectory() as tmp:
        cloud = Path(tmp) / "c.ply"
        _write_cloud(data, cloud)
        mesh = _write_mesh(data, Path(tmp) / "m")
        args = ["evaluate", str(cloud), "--mesh", str(mesh), "--json"]
        for fit in data.draw(st.lists(st.sampled_from(["plane", "plane-paper", "cylinder", "circle"]),
                                      max_size=2)):
            args += ["--fit", fit]
        if data.draw(st.booleans()):
            args += ["--z-range", f"{data.draw(st.floats(-50, 50)):.4f}", f"{data.draw(st.floats(-50, 50)):.4f}"]
        if data.draw(st.booleans()):
            args += ["--region", str(data.draw(st.integers(-1, 3)))]
        status, out, err = _run(args)
    _check_contract(args, status, out, err)
    if status == 0:
        d = json.loads(out)
        _finite_numbers(d, ("n_points", "rms_mm", "mean_abs_mm", "p95_mm", "max_mm"))
        assert d["n_points"] > 0
