"""`evaluate` warns about a cloud lying off its mesh (issue 34 item 14).

Before: a cloud 228 mm off its mesh gave ``scale_warning: null`` (only unit factors and
size ratios beyond 30 were caught).  The criterion (:func:`scheimpflug.scoring.placement_mismatch`):
the points' median distance to the mesh beyond 5 % of the mesh's bounding-box diagonal.
"""

import json

import numpy as np
import pytest
import trimesh

from scheimpflug.app.cli import main

R = 50.0    # the ball's radius [mm]; its box diagonal is 2√3·R = 173 mm


def _sphere_points(rng, n=3000, half=False):
    d = rng.normal(size=(n, 3))
    if half:
        d[:, 0] = np.abs(d[:, 0])                        # one side seen: a partial scan
    return R * d / np.linalg.norm(d, axis=1, keepdims=True)


def _evaluate(tmp_path, capsys, xyz) -> tuple[dict, str]:
    trimesh.creation.icosphere(subdivisions=4, radius=R).export(tmp_path / "ball.ply")
    (tmp_path / "c.ply").write_text("ply\nformat ascii 1.0\n" f"element vertex {len(xyz)}\nproperty double x\n"
                                    "property double y\nproperty double z\nend_header\n"
                                    + "\n".join(" ".join(map(repr, p)) for p in xyz.tolist()) + "\n")
    capsys.readouterr()
    assert main(["evaluate", str(tmp_path / "c.ply"), "--mesh", str(tmp_path / "ball.ply"), "--json"]) == 0
    cap = capsys.readouterr()
    return json.loads(cap.out), cap.err


@pytest.mark.parametrize("how, needle", [
    ("offset", "x, y, z +22"),         # the cloud: in another frame
    ("scale", "of another scale"),     # 1.3 × too large: a calibration of another binning
])
def test_a_cloud_off_its_mesh_is_warned_about(tmp_path, capsys, rng, how, needle):
    xyz = _sphere_points(rng)
    xyz = xyz + [228.0, 0.0, 0.0] if how == "offset" else 1.3 * xyz
    out, err = _evaluate(tmp_path, capsys, xyz)
    assert out["scale_warning"] and "lies off the mesh" in out["scale_warning"] and needle in out["scale_warning"]
    assert "warning: the cloud lies off the mesh" in err


def test_a_partial_noisy_scan_with_strays_on_its_mesh_is_not_warned_about(tmp_path, capsys, rng):
    xyz = _sphere_points(rng, half=True) + rng.normal(0.0, 0.2, (3000, 3))
    xyz[:300] *= 1.6                                     # 10 % strays 30 mm off
    out, err = _evaluate(tmp_path, capsys, xyz)
    assert out["scale_warning"] is None and "warning" not in err, err
    assert out["max_mm"] > 25.0                          # the strays are scored, not hidden


def test_the_criterion_is_the_median_against_a_twentieth_of_the_size(rng):
    from scheimpflug.scoring import placement_mismatch

    v = trimesh.creation.icosphere(subdivisions=2, radius=R).vertices
    size = np.linalg.norm(v.max(0) - v.min(0))
    p = _sphere_points(rng, 100)
    assert placement_mismatch(p, np.full(100, 0.049 * size), v) is None
    assert placement_mismatch(p, np.full(100, 0.051 * size), v) is not None
    d = np.r_[np.zeros(51), np.full(49, 10 * size)]          # 49 % strays do not make a cloud off its mesh
    assert placement_mismatch(p, d, v) is None
