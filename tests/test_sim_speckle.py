"""Surface-attached speckle (sim.speckle): statistics, attachment, and the triangulation limit.

References independent of the model's code:

* Fully developed speckle is a circular complex Gaussian field: intensity contrast 1;
  through a circular pupil its intensity autocovariance is |2J₁(x)/x|², x = π·r/(λ·N_w),
  whose half maximum lies at r = 0.5145·λ·N_w = 0.4217 × the grain 1.22·λ·N·(1 + m)
  (Goodman, *Speckle Phenomena in Optics*, 2007, eq. 5.x); on a sensor tilted by ψ to the
  chief ray the pattern is longer by 1/cos ψ along the tilt.
* Dorsch, Häusler & Herrmann, "Laser triangulation: fundamental uncertainty in distance
  measurement", Appl. Opt. 33, 1306 (1994): δz = C·λ / (2π·sin u_obs·sin θ).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from scheimpflug.model.camera import project_points, sensor_pose
from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.rig import load_preset

pytestmark = pytest.mark.render


def _facing_plate_pose(rig, distance_mm, yaw_deg=0.0, lift_mm=0.0):
    """Pose of a plate (face x = 0 of its frame) at the sheet point D, facing the lens."""
    g = hinge_geometry(rig)
    p = g.object_hinge_mm + distance_mm * g.propagation_dir
    n = -p / np.linalg.norm(p)                               # toward the lens
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    x = rz @ -n
    y = np.cross([0.0, 0.0, 1.0], x)
    y /= np.linalg.norm(y)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2] = x, y, np.cross(x, y)
    m[:3, 3] = p + np.array([0.0, 0.0, lift_mm])
    return m, p


def _speckle_model(rig, scene):
    from sim.speckle import SurfaceSpeckle

    return SurfaceSpeckle(rig, sensor_pose(rig), scene, seed=3)


def _plate_scene(pose):
    from sim.scene import SimScene

    plate = trimesh.creation.box([2.0, 200.0, 200.0])
    plate.apply_translation([1.0, 0.0, 0.0])
    scene = SimScene([(plate, "metal", 1)])
    scene.set_pose(pose)
    return scene


def _lit_block(rig, point, half=24):
    """A uniform 'laser' image over a block of pixels around the image of ``point``."""
    u, v = project_points(rig, point).uv_px
    img = np.zeros((rig.sensor.rows, rig.sensor.columns), np.float32)
    r0, c0 = int(v) - half, int(u) - half
    img[r0:r0 + 2 * half, c0:c0 + 2 * half] = 100.0
    return img, r0, c0


def _hwhm(profile):
    i = int(np.argmax(profile < 0.5))
    return (i - 1) + (profile[i - 1] - 0.5) / (profile[i - 1] - profile[i])


def test_fully_developed_contrast_and_grain(variant):
    from scheimpflug.model.binning import binned_rig

    rig = binned_rig(load_preset("paper"), 4)
    pose, point = _facing_plate_pose(rig, 600.0)
    model = _speckle_model(rig, _plate_scene(pose))
    img, r0, c0 = _lit_block(rig, point)
    model.pixel_speckle(img, keep_fine=True)
    s, t = model.fine, 16
    tiles = model.last_fine
    tr0, tc0 = min(k[0] for k in tiles), min(k[1] for k in tiles)
    mosaic = np.zeros(((max(k[0] for k in tiles) - tr0 + 1) * t * s,
                       (max(k[1] for k in tiles) - tc0 + 1) * t * s))
    for (tr, tc), fine in tiles.items():
        mosaic[(tr - tr0) * t * s:(tr - tr0 + 1) * t * s, (tc - tc0) * t * s:(tc - tc0 + 1) * t * s] = fine
    a, b = (r0 + 2 - tr0 * t) * s, (c0 + 2 - tc0 * t) * s
    field = mosaic[a:a + 44 * s, b:b + 44 * s]              # fully lit, away from the block edge
    assert field.mean() == pytest.approx(1.0, abs=0.03)
    assert field.std() / field.mean() == pytest.approx(1.0, abs=0.05)
    x = field - field.mean()
    acov = np.real(np.fft.ifft2(np.abs(np.fft.fft2(x)) ** 2))
    acov /= acov[0, 0]
    f = rig.lens.focal_length_mm
    grain = model.grain_px(f / (point[0] - f))
    q = pose[:3, 3]                                          # obliquity of the chief ray on the sensor
    sensor_q = -q / np.linalg.norm(q)
    cos_psi = abs(sensor_q @ sensor_pose(rig).normal)
    assert _hwhm(acov[:, 0]) / s == pytest.approx(0.4217 * grain, rel=0.15)            # rows
    assert _hwhm(acov[0, :]) / s == pytest.approx(0.4217 * grain / cos_psi, rel=0.15)  # columns


def _corr(a, b):
    a, b = a - a.mean(), b - b.mean()
    return float((a * b).sum() / math.sqrt((a * a).sum() * (b * b).sum()))


def test_speckle_is_attached_to_the_surface(variant):
    """Same position → same speckle; moved along the sheet by > 1 grain → decorrelated at the
    same pixels but found again where the surface went; turned by 2° → decorrelated."""
    rig = load_preset("paper")
    pose, point = _facing_plate_pose(rig, 600.0)
    img, r0, c0 = _lit_block(rig, point, half=20)
    first = _speckle_model(rig, _plate_scene(pose)).pixel_speckle(img)
    again = _speckle_model(rig, _plate_scene(pose)).pixel_speckle(img)
    assert np.array_equal(first, again)  # exact: same run
    import numba

    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        single = _speckle_model(rig, _plate_scene(pose)).pixel_speckle(img)
    finally:
        numba.set_num_threads(threads)
    assert np.array_equal(first, single)        # exact: threads; independent of the thread count
    # lift the plate by exactly 3 rows of image (≈ 5 grains) along the sheet
    rows_per_mm = abs(project_points(rig, point + [0, 0, 1.0]).uv_px[1]
                      - project_points(rig, point).uv_px[1])
    lift = 3.0 / rows_per_mm
    lifted, _ = _facing_plate_pose(rig, 600.0, lift_mm=lift)
    moved = _speckle_model(rig, _plate_scene(lifted)).pixel_speckle(img)
    inner = (slice(r0 + 6, r0 + 34), slice(c0 + 6, c0 + 34))
    up = (slice(r0 + 3, r0 + 31), slice(c0 + 6, c0 + 34))   # the surface moved up 3 rows
    assert first[inner].std() > 0.2
    assert abs(_corr(first[inner], moved[inner])) < 0.25
    assert _corr(first[inner], moved[up]) > 0.8
    turned, _ = _facing_plate_pose(rig, 600.0, yaw_deg=2.0)
    rotated = _speckle_model(rig, _plate_scene(turned)).pixel_speckle(img)
    slight, _ = _facing_plate_pose(rig, 600.0, yaw_deg=0.02)
    barely = _speckle_model(rig, _plate_scene(slight)).pixel_speckle(img)
    assert abs(_corr(first[inner], rotated[inner])) < 0.25
    assert _corr(first[inner], barely[inner]) > 0.8


def test_stripe_scatter_matches_dorsch_limit(variant):
    """Stripe-centre scatter from speckle vs δz = λ/(2π·sin u_obs·sin θ) at three distances.

    Dorsch et al.'s regime: the spot (here the stripe, the laser focused on the plate) about
    as wide as a speckle grain — f/16 with the paper rig's 150 µm sheet waist.
    """
    from scheimpflug.stripe import extract_stripes
    from sim.render import Renderer, RenderSettings
    from sim.scene import SimScene
    from sim.truth import laser_origin_mm

    base = load_preset("paper").replace(lens={"f_number": 16.0}, laser={"speckle_contrast": 1.0},
                                        environment={"ambient_irradiance_w_m2": 0.0})
    g = hinge_geometry(base)
    plate = trimesh.creation.box([5.0, 200.0, 30.0])
    plate.apply_translation([2.5, 0.0, 15.0])
    for distance in (470.0, 585.0, 700.0):
        point = g.object_hinge_mm + distance * g.propagation_dir
        rig = base.replace(laser={"waist_distance_mm": float(np.linalg.norm(point - laser_origin_mm(base)))})
        pose = np.eye(4)
        pose[:3, 0], pose[:3, 1], pose[:3, 2] = g.propagation_dir, g.sheet_normal, [0.0, 0.0, 1.0]
        pose[:3, 3] = point - [0.0, 0.0, 15.0]
        centres = []
        for speckle in (True, False):
            r = Renderer(rig, SimScene([(plate, "metal", 1)]),
                         RenderSettings(samples_per_row=32, speckle=speckle))
            centres.append(extract_stripes(r.render(pose, 1), "cog", window_px=6))
        rows, ia, ib = np.intersect1d(centres[0].rows, centres[1].rows, return_indices=True)
        du = (centres[0].u[ia] - centres[1].u[ib])[5:-5]          # same splats: speckle only
        d_mm = float(g.distance_from_column(np.median(centres[1].u[ib])))
        dz = np.std(du) * d_mm**2 / abs(g.F2_px_mm)
        dist = np.linalg.norm(point)
        sin_u = 0.5 * rig.lens.focal_length_mm / rig.lens.f_number / dist
        sin_theta = np.linalg.norm(np.cross(g.propagation_dir, -point / dist))
        dorsch = rig.laser.wavelength_nm * 1e-6 / (2 * math.pi * sin_u * sin_theta)
        assert dz == pytest.approx(dorsch, rel=0.3), distance
