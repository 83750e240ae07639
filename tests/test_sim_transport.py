"""Multi-bounce light transport (sim.transport): against Mitsuba's own integrator and mirror geometry.

References independent of the twin's transport code:

* Mitsuba's particle tracer (``ptracer``) with its ``thinlens`` camera renders the same
  meshes and BSDFs under a point light; its pixel values (radiance-normalised) are turned
  into pixel flux with the thin-lens camera equation Φ = L·A_ap·p²·cos⁴θ/s'² (from the
  camera's importance W_e = 1/(A_img·A_ap·cos⁴θ), Mitsuba ``src/sensors/thinlens.cpp``).
* A 90° metal dihedral whose edge bisects the laser and viewing directions returns the
  twice-reflected light toward the lens; the test computes the secondary stripe by
  reflecting the laser rays on the two planes (specular geometry) and projecting.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from scheimpflug.model.camera import SensorPose, project_points
from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.rig import load_preset

pytestmark = pytest.mark.render


# ------------------------------------------------------------------ Mitsuba comparison
F_MM, F_NUMBER, FOCUS_MM = 50.0, 4.0, 400.0
S_MM = F_MM * FOCUS_MM / (FOCUS_MM - F_MM)          # sensor distance behind the lens
COLS, ROWS, PITCH_MM = 64, 48, 0.2
LIGHT_MM = np.array([340.0, -40.0, 45.0])


def corner_parts():
    """A diffuse back wall facing the camera and a rough-metal floor tilted toward it."""
    wall = trimesh.creation.box([4.0, 160.0, 160.0])
    wall.apply_translation([432.0, 0.0, 20.0])
    floor = trimesh.creation.box([120.0, 160.0, 4.0])
    floor.apply_transform(trimesh.transformations.rotation_matrix(math.radians(-25), [0, 1, 0]))
    floor.apply_translation([385.0, 0.0, -8.0])
    return [(wall, "tape", 1), (floor, "knurled-metal", 2)]


def twin_flux(bounces, n_rays, seed):
    """The twin's pixel flux [W] of the corner under a 1 W/sr point light, untilted sensor."""
    from sim.render import Renderer, RenderSettings
    from sim.scene import SimScene

    rig = load_preset("paper").replace(
        lens={"focal_length_mm": F_MM, "f_number": F_NUMBER},
        environment={"ambient_irradiance_w_m2": 0.0}, twin={"bounces": bounces},
        sensor={"columns": COLS, "rows": ROWS})
    pose = SensorPose(np.array([-S_MM, -(COLS / 2 - 0.5) * PITCH_MM, -(ROWS / 2 - 0.5) * PITCH_MM]),
                      np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), PITCH_MM, COLS, ROWS)
    settings = RenderSettings(secondary_thinning=1, rr_depth=100, pixel_filter="box")
    r = Renderer(rig, SimScene(corner_parts()), settings, pose=pose)
    light = r.render_point_light(np.eye(4), LIGHT_MM, 1.0, [0.0, 0.0, -1.0], 180.0, n_rays, seed)
    return light.laser.astype(np.float64) / r.electrons_per_watt


def mitsuba_flux(bounces, spp):
    """Mitsuba ptracer (max_depth = bounces + 1) with a thinlens camera → pixel flux [W]."""
    import mitsuba as mi

    from sim.scene import SimScene

    shapes = {s.id(): s for s in SimScene(corner_parts()).scene.shapes()}
    fov = 2 * math.degrees(math.atan(COLS * PITCH_MM / 2 / S_MM))
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "ptracer", "max_depth": bounces + 1, "rr_depth": 100},
        "sensor": {"type": "thinlens", "fov": fov, "fov_axis": "x",
                   "aperture_radius": 0.5 * F_MM / F_NUMBER, "focus_distance": FOCUS_MM,
                   "near_clip": 1.0, "far_clip": 1e4,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 0], target=[1, 0, 0],
                                                              up=[0, 0, 1]),
                   "film": {"type": "hdrfilm", "width": COLS, "height": ROWS,
                            "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                   "sampler": {"type": "independent", "sample_count": spp}},
        "light": {"type": "point", "position": LIGHT_MM.tolist(),
                  "intensity": {"type": "rgb", "value": [1.0, 1.0, 1.0]}},
        **shapes})
    radiance = np.asarray(mi.render(scene, seed=3), np.float64)[..., 2]   # blue = 450 nm channel
    u = (np.arange(COLS) - COLS / 2 + 0.5) * PITCH_MM
    v = (np.arange(ROWS) - ROWS / 2 + 0.5) * PITCH_MM
    cos4 = (S_MM**2 / (S_MM**2 + u[None, :] ** 2 + v[:, None] ** 2)) ** 2
    aperture = math.pi * (0.5 * F_MM / F_NUMBER) ** 2
    return radiance * aperture * cos4 * PITCH_MM**2 / S_MM**2


@pytest.mark.parametrize("bounces", [1, 3])
def test_flux_matches_mitsuba_particle_tracer(variant, bounces):
    twin = twin_flux(bounces, 12_000_000, seed=1)
    ref = mitsuba_flux(bounces, 3072)
    region_twin = twin.reshape(2, 24, 4, 16).sum(axis=(1, 3))   # 8 regions of 24 × 16 px
    region_ref = ref.reshape(2, 24, 4, 16).sum(axis=(1, 3))
    lit = region_ref > 0.1 * region_ref.max()
    assert lit.sum() >= 6
    assert twin.sum() == pytest.approx(ref.sum(), rel=0.01)
    np.testing.assert_allclose(region_twin[lit], region_ref[lit], rtol=0.02)


# ------------------------------------------------------------------ V-groove
def _rotate(v, axis, angle):
    return v * math.cos(angle) + np.cross(axis, v) * math.sin(angle) \
        + axis * (axis @ v) * (1 - math.cos(angle))


def dihedral(rig, distance_mm=600.0):
    """A 90° metal V-groove whose edge crosses the sheet at D, oriented to retro-reflect to the lens.

    Returns (mesh, edge point E, laser origin, face normals n_A, n_B (into the groove)).
    """
    from sim.truth import laser_origin_mm

    g = hinge_geometry(rig)
    edge = g.object_hinge_mm + distance_mm * g.propagation_dir
    laser = laser_origin_mm(rig)
    d = (edge - laser) / np.linalg.norm(edge - laser)
    c = -edge / np.linalg.norm(edge)                  # toward the lens centre
    a = (d + c) / np.linalg.norm(d + c)               # 2(d·a)a − d = c: back into the lens
    opening = c - d - ((c - d) @ a) * a
    opening /= np.linalg.norm(opening)
    normals = [_rotate(opening, a, math.radians(s)) for s in (45.0, -45.0)]
    faces = []
    for n in normals:
        along = np.cross(a, n)
        along = along if along @ opening > 0 else -along
        m = trimesh.creation.box([25.0, 80.0, 1.5])
        m.apply_translation([12.5, 0.0, -0.75])
        pose = np.eye(4)
        pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = along, a, n, edge
        m.apply_transform(pose)
        faces.append(m)
    return trimesh.util.concatenate(faces), edge, laser, normals


def mirror_stripe(rig, edge, laser, n_a, n_b):
    """Secondary stripe by specular geometry: sheet ∩ face A, reflect the laser ray on A, hit B."""
    g = hinge_geometry(rig)
    along_a = np.cross(g.sheet_normal, n_a)
    along_a /= np.linalg.norm(along_a)
    if along_a[2] * n_b[2] < 0:       # go up the face that the sheet crosses toward B's side
        along_a = -along_a
    p_a = edge + np.linspace(0.2, 20.0, 500)[:, None] * along_a
    d = (p_a - laser) / np.linalg.norm(p_a - laser, axis=1, keepdims=True)
    d1 = d - 2 * (d @ n_a)[:, None] * n_a
    t = ((edge - p_a) @ n_b) / (d1 @ n_b)
    return project_points(rig, p_a + t[:, None] * d1).uv_px


def test_v_groove_secondary_stripe_at_mirror_position(variant):
    from scheimpflug.model.binning import binned_rig
    from sim.materials import MaterialSettings
    from sim.render import Renderer, RenderSettings
    from sim.scene import SimScene

    rig = binned_rig(load_preset("paper"), 2).replace(environment={"ambient_irradiance_w_m2": 0.0})
    mesh, edge, laser, (n_a, n_b) = dihedral(rig)
    expected = mirror_stripe(rig, edge, laser, n_a, n_b)
    rows = np.arange(int(expected[:, 1].min()) + 8, int(expected[:, 1].max()) - 8)
    u_exp = np.interp(rows, expected[:, 1], expected[:, 0])
    images = {}
    for bounces in (1, 2):
        scene = SimScene([(mesh, "metal", 1)], MaterialSettings(metal_alpha=0.05))
        r = Renderer(rig.replace(twin={"bounces": bounces}), scene,
                     RenderSettings(samples_per_row=128, secondary_thinning=1))
        images[bounces] = r.render(np.eye(4), 1).astype(np.float64)
    cols = np.rint(u_exp).astype(int)[:, None] + np.arange(-10, 11)
    win = {b: np.take_along_axis(img[rows], cols, 1) for b, img in images.items()}
    centre = (win[2] * cols).sum(1) / win[2].sum(1)
    assert np.median(np.abs(centre - u_exp)) < 0.5
    assert abs(np.mean(centre - u_exp)) < 1.0
    assert np.percentile(np.abs(centre - u_exp), 90) < 1.5
    assert win[1].sum() < 1e-3 * win[2].sum()       # bounces = 1: no secondary stripe


# ------------------------------------------------------------------ determinism
def test_multibounce_subsurface_frames_bit_identical_across_threads(variant):
    import drjit as dr

    from scheimpflug.model.binning import binned_rig
    from sim import transport
    from sim.scenarios import rotary_scenario
    from sim.writer import MitsubaTwin

    rig = binned_rig(load_preset("paper"), 4).replace(twin={"bounces": 3, "subsurface": True})
    scenario = rotary_scenario(rig, part="pile", step_deg=1, frames=2)
    frame, other = scenario.frames
    twin = MitsubaTwin(rig, scenario.assembly, spp=16)
    twin.renderer.render_light(other.rig_from_part, other.seed)    # fills the kernel caches
    a = twin.renderer.render_light(frame.rig_from_part, frame.seed)
    threads = dr.thread_count()
    dr.set_thread_count(1)
    try:
        b = twin.renderer.render_light(frame.rig_from_part, frame.seed)
    finally:
        dr.set_thread_count(threads)
    c = twin.renderer.render_light(frame.rig_from_part, frame.seed + 1)
    transport._SENSOR_KERNELS.clear()       # a frame does not depend on the frames before
    transport._SURFACE_KERNELS.clear()
    d = twin.renderer.render_light(frame.rig_from_part, frame.seed)
    assert a.walks[0] > 0 and a.secondary.sum() > 0
    assert np.array_equal(a.image, b.image) and np.array_equal(a.secondary, b.secondary)  # exact: threads
    assert np.array_equal(a.image, d.image) and np.array_equal(a.secondary, d.secondary)
    assert not np.array_equal(a.image, c.image)
