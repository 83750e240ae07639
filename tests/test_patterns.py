"""Printed patterns (scenes.patterns) and their textures in the renderer (sim.textures, sim.scene).

References: OpenCV's own board images (``CharucoBoard.generateImage``), the numpy reference
albedo of scenes.patterns against the Dr.Jit one, and the geometry of a bent sheet
(arc length kept).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import ndimage

from scenes.patterns import (
    BLACK_ALBEDO,
    WHITE_ALBEDO,
    parse_pattern,
    print_points_mm,
    target_assembly,
    texture_albedo,
)
from scheimpflug.errors import MeshError


# ------------------------------------------------------------------ specs
def test_specs_parse_to_their_grids():
    cb = parse_pattern("chessboard:10x8:7")
    assert (cb.kind, cb.grid_shape, cb.pitch_mm, cb.text) == ("chessboard", (10, 8), 7.0, "chessboard:10x8:7")
    ids = cb.corner_ids()
    assert ids.shape == (80, 2) and ids[1].tolist() == [1, 0] and ids[10].tolist() == [0, 1]   # row-major
    np.testing.assert_array_equal(cb.corners_mm()[11], [7.0, 7.0])  # exact: copy
    assert cb.extent_mm() == (-7.0, -7.0, 70.0, 56.0)
    ch = parse_pattern("charuco:5x4:10:7")
    assert ch.grid_shape == (4, 3) and ch.dictionary == "DICT_4X4_50"
    ci = parse_pattern("circles:7x6:10")
    assert ci.diameter_mm == 5.0 and ci.extent_mm() == (-2.5, -2.5, 62.5, 52.5)
    assert parse_pattern(ci.text) == ci and parse_pattern(ch.text) == ch


@pytest.mark.parametrize("spec, words", [
    ("triangle:4x4:5", "unknown pattern"), ("chessboard:10x8", "chessboard:COLSxROWS:SQUARE_MM"),
    ("chessboard:10by8:7", "is not COLSxROWS"), ("chessboard:1x8:7", "at least 2x2"),
    ("chessboard:10x8:-7", "must be a number > 0"), ("chessboard:10x8:seven", "is not a number"),
    ("charuco:5x4:10:12", "smaller than the square"), ("charuco:5x4:10:7:DICT_9X9_1", "unknown ArUco"),
    ("charuco:20x20:10:7:DICT_4X4_50", "holds 50 markers"), ("circles:4x4:10:12", "touch"), ("", "empty"),
])
def test_bad_specs_are_refused_in_one_line(spec, words):
    with pytest.raises(MeshError) as err:
        parse_pattern(spec)
    assert words in str(err.value) and "\n" not in str(err.value)


def test_a_pattern_larger_than_its_plate_is_refused():
    with pytest.raises(MeshError, match=r"needs a plate of at least 91 × 77 mm; the plate is 80 × 80 mm"):
        target_assembly("chessboard:10x8:7", plate_mm=(80.0, 80.0))
    assert len(target_assembly("chessboard:10x8:7", plate_mm=(91.0, 77.0)).parts) == 2
    for kwargs, words in (({"border_mm": -1.0}, "border"), ({"thickness_mm": 0.0}, "thickness"),
                          ({"bow_mm": 40.0}, "bow"), ({"white": 1.5}, "albedo")):
        with pytest.raises(MeshError, match=words):
            target_assembly("chessboard:10x8:7", **kwargs)


# ------------------------------------------------------------------ albedo
def test_charuco_texture_is_opencvs_board():
    """Our ChArUco albedo sampled at pixel centres = OpenCV's generateImage, away from edges."""
    import cv2

    spec = parse_pattern("charuco:5x4:10:7")
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    board = cv2.aruco.CharucoBoard((5, 4), 10.0, 7.0, d)
    img = board.generateImage((1000, 800), marginSize=0, borderBits=1)        # 20 px/mm
    yy, xx = np.mgrid[0:800, 0:1000]
    ours = texture_albedo(spec.texture(0.0, 1.0), np.stack([(xx + 0.5) / 20 - 10, (yy + 0.5) / 20 - 10], -1))
    flat = ndimage.minimum_filter(ours, 5) == ndimage.maximum_filter(ours, 5)   # ≥ 2 px from an edge
    assert flat.mean() > 0.9
    np.testing.assert_array_equal(ours[flat] * 255, img[flat])  # exact: integers
    # and OpenCV finds its markers in our rendering of the texture (ids as its own)
    found, ids, _ = cv2.aruco.ArucoDetector(d).detectMarkers((ours * 255).astype(np.uint8))
    assert sorted(ids.ravel().tolist()) == list(range(10))


def test_chessboard_and_circles_albedo_by_definition():
    cb = parse_pattern("chessboard:3x2:10").texture()
    pts = np.array([[-5, -5], [5, -5], [5, 5], [15, 15], [35, 15], [-15, 0], [0.0, 25.0]])
    np.testing.assert_array_equal(texture_albedo(cb, pts),  # exact: copy
                                  [BLACK_ALBEDO, WHITE_ALBEDO, BLACK_ALBEDO, BLACK_ALBEDO, WHITE_ALBEDO,
                                   WHITE_ALBEDO, WHITE_ALBEDO])
    ci = parse_pattern("circles:3x2:10:4").texture(0.0, 1.0)
    # exact: copy
    np.testing.assert_array_equal(texture_albedo(ci, [[0, 0], [1.9, 0], [2.1, 0], [20, 10], [5, 5], [30, 0]]),
                                  [0, 0, 1, 0, 1, 1])


@pytest.mark.parametrize("spec", ["chessboard:10x8:7", "charuco:6x5:12:9:DICT_5X5_100", "circles:5x4:8"])
def test_the_renderers_texture_is_the_reference(variant, spec, rng):
    """sim.textures (Dr.Jit, float32) = scenes.patterns.texture_albedo (numpy) away from edges."""
    import drjit as dr
    import mitsuba as mi

    from sim.textures import texture_function

    t = parse_pattern(spec).texture()
    uv = rng.uniform(-15, 90, (20000, 2))
    ref = texture_albedo(t, uv)
    got = np.asarray(texture_function(t, mi, dr)(mi.Point2f(uv[:, 0].astype(np.float32), uv[:, 1].astype(np.float32))))
    jitter = [texture_albedo(t, uv + e) for e in ([1e-3, 0], [-1e-3, 0], [0, 1e-3], [0, -1e-3])]
    clear = np.all([j == ref for j in jitter], axis=0)
    assert clear.mean() > 0.99
    np.testing.assert_allclose(got[clear], ref[clear], rtol=1e-6)


def test_image_texture_is_bilinear_between_texel_centres(variant):
    import drjit as dr
    import mitsuba as mi

    from sim.textures import texture_function

    t = {"kind": "image", "albedo": np.array([[0.0, 1.0], [0.5, 0.5]]), "extent_mm": [0.0, 0.0, 2.0, 2.0]}
    uv = np.array([[0.5, 0.5], [1.5, 0.5], [1.0, 0.5], [1.0, 1.0], [-3.0, 0.5], [1.0, 9.0]])
    expected = [0.0, 1.0, 0.5, 0.5, 0.0, 0.5]
    np.testing.assert_allclose(texture_albedo(t, uv), expected)
    got = texture_function(t, mi, dr)(mi.Point2f(uv[:, 0].astype(np.float32), uv[:, 1].astype(np.float32)))
    np.testing.assert_allclose(np.asarray(got), expected, atol=1e-6)


# ------------------------------------------------------------------ the printed target
def test_bowed_print_keeps_printed_distances_and_its_sagitta():
    asm = target_assembly("chessboard:10x8:7", bow_mm=1.5)
    pr, plate = asm.parts
    x0, y0, x1, y1 = pr.analytic["print_mm"]
    s = np.linspace(x0, x1, 2001)
    p = print_points_mm(pr.analytic, np.stack([s, np.zeros_like(s)], 1))
    arc = np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1))
    assert arc == pytest.approx(x1 - x0, rel=1e-6)           # arc length = printed width
    assert p[:, 2].min() == pytest.approx(-1.5, abs=1.1e-4)   # centre 1.5 mm toward the reader (chords ≤ 0.1 µm off)
    assert abs(p[0, 2]) < 1e-9 and abs(p[-1, 2]) < 1e-9
    # the mesh's texture coordinates are those arc lengths, and its vertices the same points
    v = np.asarray(pr.mesh.vertices)
    np.testing.assert_allclose(print_points_mm(pr.analytic, pr.uv_mm), v, atol=1e-9)
    # the plate stays behind the print
    assert plate.mesh.bounds[0, 2] > p[:, 2].max()


def test_target_print_is_rendered_with_its_texture(variant):
    """A ray at a black square's centre sees the black albedo, at a white square's the white."""
    import mitsuba as mi

    from sim.scene import SimScene

    sc = SimScene(target_assembly("chessboard:4x3:10").parts)
    xs = np.array([-5.0, 5.0, 35.0, 45.0], np.float32)
    ray = mi.Ray3f(mi.Point3f(mi.Float(xs), -5.0, -50.0), mi.Vector3f(0.0, 0.0, 1.0))
    si = sc.scene.ray_intersect(ray)
    np.testing.assert_allclose(np.asarray(sc.albedo_dr(si)), [BLACK_ALBEDO, WHITE_ALBEDO, BLACK_ALBEDO, WHITE_ALBEDO],
                               rtol=1e-6)
    assert math.isclose(float(np.asarray(si.t)[0]), 50.0, rel_tol=1e-6)
