"""A twin's unknowns from a scan's own frames (:mod:`sim.identify.scan`, issue 36 item 1).

The closed loop: a tiny twin (FabScan's rig from its own calibration, 4 × 4 binned, or a
synthetic ordinary camera where FabScan's config is absent; a sphere as the part) renders
"real" frames at known values of its unknowns with a seed of its own, imported as real
frames are; :func:`identify_scan` must find those values inside its 90 % intervals.

The image-level figures are :func:`scheimpflug.compare.figures.folder_figures` (``compare``'s).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from scheimpflug.errors import StudyError

REAL = Path(__file__).resolve().parents[2] / "shared" / "realdata"
CONFIG = REAL / "fabscan" / "dummy.config.json"
TRUTH = {"laser.power_mw": 9.0, "chain.glare_fraction": 0.12}
PRIORS = {"laser.power_mw": {"range": [2.0, 30.0], "prior": "log-uniform"},
          "chain.glare_fraction": {"range": [0.0, 0.3]}}
REGIONS = {"part": (200.0, 298.0), "table": (302.0, 380.0)}


def _rig_tables(tmp_path) -> dict:
    from scheimpflug.model.binning import binned_rig
    from scheimpflug.model.rig import load_rig, rig_to_dict

    if CONFIG.is_file():
        from scheimpflug.app.cli import main

        path = tmp_path / "fab.toml"
        assert main(["rig", "from-calibration", str(CONFIG), "--preset", "rpi-v2-binned", "--chain",
                     "raspberry_pi_v2", "--out", str(path)]) == 0
        return rig_to_dict(binned_rig(load_rig(path), 4))
    pytest.skip(f"FabScan's config absent ({CONFIG}): the closed loop needs its rig")


def _twin(tmp_path) -> Path:
    import trimesh

    from scheimpflug.model.rig import rig_from_dict, rig_to_toml

    twin = tmp_path / "twin"
    twin.mkdir()
    (twin / "rig.toml").write_text(rig_to_toml(rig_from_dict(_rig_tables(tmp_path))))
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=20.0)
    mesh.apply_translation([0.0, 0.0, 20.0])
    mesh.export(twin / "part.ply")
    return twin


def _real_scan(twin: Path, out: Path, angles, values: dict) -> Path:
    """The twin's frames at ``values``, imported as real frames are (``scheimpflug import --channel r``)."""
    from scheimpflug.app.cli import main
    from scheimpflug.model.rig import load_rig, rig_to_dict
    from sim.identify.scan import render_at_angles
    from sim.study.spec import _with_value

    tables = rig_to_dict(load_rig(twin / "rig.toml"))
    for k, v in values.items():
        tables = _with_value(tables, k, v)
    rendered = render_at_angles(tables, twin / "part.ply", None, angles, out / "render", seed=987654)
    files = sorted(str(p) for p in (rendered / "frames").glob("*.jpg"))
    assert main(["import", *files, "--channel", "r", "--stripe-along", "rows", "--quiet",
                 f"--angles-deg={','.join(f'{a:g}' for a in angles)}", "--out", str(out / "real")]) == 0
    return out / "real"


@pytest.mark.slow
@pytest.mark.render
def test_closed_loop_recovers_the_twins_own_values(tmp_path, variant):
    from sim.identify.scan import identify_scan

    twin = _twin(tmp_path)
    real = _real_scan(twin, tmp_path, [-360.0, -300.0, -240.0, -180.0, -120.0, -60.0], TRUTH)
    seen = []
    res = identify_scan(twin, real, REGIONS, fit_frames=[0, 2, 4], held_frames=[1, 3], out=tmp_path / "id",
                        unknowns=PRIORS, runs=12, refine=0, seed=5, progress=lambda d, t: seen.append((d, t)),
                        part_material="metal")
    assert seen[-1] == (14, 14) and res["runs"]["count"] == 14
    for key, truth in TRUTH.items():
        got = res["identified"][key]
        assert got["lo90"] <= truth <= got["hi90"], (key, truth, got)
    power = res["identified"]["laser.power_mw"]
    assert power["hi90"] / power["lo90"] < 2.0           # the stripe's level pins the power (prior: 15 ×)
    # the frames it was not fitted on, predicted: the same twin, so most figures inside their 90 % intervals
    inside = [r["inside"] for r in res["figures"]["held_out"].values() if r["inside"] is not None]
    assert len(inside) >= 6 and sum(inside) >= 2 * len(inside) / 3, res["figures"]["held_out"]
    rig = (tmp_path / "id" / "identified.toml").read_text()
    assert f"power_mw = {power['value']:.4g}" in rig
    # a rerun resumes: no run again, the same result
    again = identify_scan(twin, real, REGIONS, fit_frames=[0, 2, 4], held_frames=[1, 3], out=tmp_path / "id",
                          unknowns=PRIORS, runs=12, refine=0, seed=5, part_material="metal", workers=1)
    assert again["identified"] == res["identified"]
    print(json.dumps({k: {q: round(v[q], 4) for q in ("value", "lo90", "hi90")}
                      for k, v in res["identified"].items()}), res["runs"])


def test_default_frames_spread_and_parity():
    from sim.identify.scan import default_frames

    even, odd = default_frames(200, 0), default_frames(200, 1)
    assert len(even) == 6 and len(odd) == 6
    assert all(f % 2 == 0 for f in even) and all(f % 2 == 1 for f in odd)
    assert not set(even) & set(odd) and even[0] == 0 and even[-1] > 150
    assert default_frames(1, 1) == [] and default_frames(3, 0) == [0, 2]


@pytest.mark.parametrize("case, words", [
    ("no-rig", "has no rig.toml"),
    ("overlap", "fitted and held out"),
    ("no-held", "too few to hold any out"),
    ("region", "region 'part'"),
    ("size", "the twin's sensor is"),
    ("no-angle", "without angle_deg"),
])
def test_bad_input_is_one_clear_error_and_nothing_written(tmp_path, paper_rig, case, words):
    import cv2

    from scheimpflug.model.rig import rig_to_toml
    from sim.identify.scan import identify_scan

    rig = paper_rig
    twin = tmp_path / "twin"
    twin.mkdir()
    if case != "no-rig":
        (twin / "rig.toml").write_text(rig_to_toml(rig))
    (twin / "part.ply").write_text("ply\n")
    real = tmp_path / "real"
    (real / "frames").mkdir(parents=True)
    rows, cols = (10, 10) if case == "size" else (rig.sensor.rows, rig.sensor.columns)
    frames = []
    for i in range(4):
        cv2.imwrite(str(real / "frames" / f"{i:05d}.png"), np.zeros((rows, cols), np.uint8))
        entry = {"file": f"frames/{i:05d}.png"}
        if case != "no-angle":
            entry["angle_deg"] = 90.0 * i
        frames.append(entry)
    (real / "manifest.json").write_text(json.dumps({"format": "scheimpflug-frames/1", "complete": True,
                                                    "frames": frames, "stripe_along": "columns"}))
    fit, held = [0, 2], ([2] if case == "overlap" else [] if case == "no-held" else [1])
    regions = {"part": (50.0, 10.0)} if case == "region" else {"part": (0.0, 100.0)}
    with pytest.raises(StudyError, match=words):
        identify_scan(twin, real, regions, fit_frames=fit, held_frames=held, out=tmp_path / "out")
    assert not (tmp_path / "out").exists()


def _die(plan, out):
    """A run whose worker process ends abruptly (as the kernel's OOM killer ends it)."""
    import os

    os._exit(9)


def test_a_dying_run_worker_is_one_clear_error(tmp_path, monkeypatch):
    """A worker killed mid-batch (memory) gives the scan identification's error, not the pool's."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor
    from types import SimpleNamespace

    from sim.identify import scan

    monkeypatch.setattr(scan, "_worker_run", _die)
    monkeypatch.setattr(scan, "_run_pool", lambda s, workers: ProcessPoolExecutor(
        1, mp_context=multiprocessing.get_context("spawn")))
    plans = [SimpleNamespace(index=k) for k in range(2)]
    with pytest.raises(StudyError, match=r"worker process ended unexpectedly .*rerun to resume"):
        scan._runs(plans, None, tmp_path, scan._Counter(None, 2, workers=1))
