"""The camera pass (sim.camera_pass, sim.lights, sim.textures) against closed forms and Mitsuba's own camera.

References are independent of the renderer: the étendue integral by Gauss quadrature, the
configuration factor of a rectangle (Howell C-11), the thin-lens circle of confusion of
scheimpflug.model.camera (rim rays), and Mitsuba's ``thinlens`` sensor with its ``path``
integrator and ``checkerboard`` texture.  Poses are built here from the docs/reference/interface.md
conventions.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from scheimpflug.errors import RenderError
from scheimpflug.model.camera import SensorPose, blur_footprint_px, project_points, sensor_pose
from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.rig import load_preset

pytestmark = pytest.mark.render

PHOTON_450_J = 6.62607015e-34 * 299792458.0 / 450e-9
E_Z = np.array([0.0, 0.0, 1.0])


# ------------------------------------------------------------------ helpers
def electrons_per_watt(rig):
    return rig.sensor.exposure_ms * 1e-3 * rig.sensor.quantum_efficiency / PHOTON_450_J


def etendue_mm2_sr(rig, pose, uv_px, n_pix=4, n_r=6, n_phi=16):
    """∫_pixel ∫_aperture cos θ_q cos θ_A / |q − A|² dA dA_q by Gauss quadrature [mm²·sr], per pixel (n,)."""
    a = 0.5 * rig.lens.focal_length_mm / rig.lens.f_number
    xg, wg = np.polynomial.legendre.leggauss(n_pix)
    rg, wr = np.polynomial.legendre.leggauss(n_r)
    r = 0.5 * (rg + 1) * a
    w_r = 0.5 * wr * a * r                                     # ∫ r dr
    phi = (np.arange(n_phi) + 0.5) * 2 * np.pi / n_phi
    ap = np.stack([np.zeros((n_r, n_phi)), r[:, None] * np.cos(phi), r[:, None] * np.sin(phi)], -1).reshape(-1, 3)
    w_ap = (w_r[:, None] * np.full(n_phi, 2 * np.pi / n_phi)).ravel()
    out = []
    for u, v in np.atleast_2d(uv_px):
        du, dv = np.meshgrid(0.5 * xg, 0.5 * xg)
        wq = np.outer(0.5 * wg, 0.5 * wg).ravel() * pose.pitch_mm**2
        q = pose.origin_mm + ((u + du.ravel())[:, None] * pose.u_dir + (v + dv.ravel())[:, None] * pose.v_dir) \
            * pose.pitch_mm
        w = ap[None] - q[:, None]
        d2 = (w**2).sum(-1)
        g = np.abs(w[..., 0]) * np.abs(w @ pose.normal) / d2**2
        out.append(float((g * wq[:, None] * w_ap[None]).sum()))
    return np.array(out)


def plate_mesh(width_mm=300.0, height_mm=300.0, thickness_mm=2.0):
    """Plate in its own frame: measured face z = 0 (facing −z), x, y in [−w/2, w/2] × [−h/2, h/2]."""
    m = trimesh.creation.box([width_mm, height_mm, thickness_mm])
    m.apply_translation([0.0, 0.0, thickness_mm / 2])
    return m


def facing(origin, x_axis, y_axis):
    """(4, 4) rig_from_part with the given x, y axes (z = x × y) at ``origin``."""
    m = np.eye(4)
    x = np.asarray(x_axis, float) / np.linalg.norm(x_axis)
    y = np.asarray(y_axis, float) - (np.asarray(y_axis, float) @ x) * x
    y /= np.linalg.norm(y)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, y, np.cross(x, y), origin
    return m


def toward_camera(g, point):
    """The sheet normal oriented toward the lens centre."""
    n = g.sheet_normal
    return n if n @ (-point) > 0 else -n


class Textured:
    """A part with a texture (duck-typed like scenes.Part)."""

    def __init__(self, mesh, texture, uv=None, material="paper", object_id=1):
        self.mesh, self.texture, self.uv_mm = mesh, texture, uv
        self.material, self.object_id, self.name = material, object_id, "textured"


def chessboard_texture(square_mm, cols=60, rows=60, black=0.05, white=0.85):
    from scenes.patterns import parse_pattern

    return parse_pattern(f"chessboard:{cols}x{rows}:{square_mm}").texture(black, white)


def make_pass(rig, parts, pose=None, flood="rig", **settings):
    from sim.camera_pass import CameraPass, CameraSettings
    from sim.scene import SimScene

    return CameraPass(rig, SimScene(parts), CameraSettings(**settings), pose=pose, flood=flood)


def untilted_pose(rig, image_distance_mm, columns, rows, pitch_mm):
    """A sensor ⊥ the optical axis at x = −x', centred on it (columns → −y, rows → −z on the object side)."""
    e_u, e_v = np.array([0.0, 1.0, 0.0]), E_Z
    origin = np.array([-image_distance_mm, 0.0, 0.0]) - 0.5 * (columns - 1) * pitch_mm * e_u \
        - 0.5 * (rows - 1) * pitch_mm * e_v
    return SensorPose(origin, e_u, e_v, pitch_mm, columns, rows)


# ------------------------------------------------------------------ radiometry
def test_environment_lit_plate_gives_the_etendue_closed_form(variant, rng):
    """Uniform E on a Lambertian plate: e⁻ = ρ·E/π · ∫∫ cos θ_q cos θ_A/|q − A|² · t·QE/(hν), within 2 %."""
    from sim.camera_pass import sensor_window

    rig = load_preset("paper").replace(environment={"ambient_irradiance_w_m2": 1.0})
    g = hinge_geometry(rig)
    centre = g.rig_from_sheet(600.0, 0.0)
    # a plate in the sheet, so that every ray of the window meets it (in focus or not: L is uniform)
    part_pose = facing(centre, g.propagation_dir, -E_Z)
    pose = sensor_window(sensor_pose(rig), 200, 700, 800, 48)
    cp = make_pass(rig, [(plate_mesh(), "cardboard", 1)], pose=pose, spp=8, pixel_filter="box")
    img = cp.render(part_pose, seed=3)
    uv = np.stack([rng.integers(0, 800, 40), rng.integers(0, 48, 40)], 1).astype(float)
    expected = 0.35 / math.pi * 1.0 * etendue_mm2_sr(rig, pose, uv) * 1e-6 * electrons_per_watt(rig)
    got = img[uv[:, 1].astype(int), uv[:, 0].astype(int)]
    np.testing.assert_allclose(got, expected, rtol=0.02)
    # the tilted sensor's falloff is in it: the corner pixels differ from the chief-ray cos⁴ of an untilted one
    assert np.ptp(expected) / expected.mean() > 0.01


def test_flood_light_gives_its_configuration_factor_irradiance(variant):
    """A plate through the aim point, facing the flood light: the aim's pixel gets ρ·E_flood/π·G within 2 %."""
    from sim.camera_pass import sensor_window
    from sim.lights import flood_light

    rig = load_preset("paper").replace(environment={"ambient_irradiance_w_m2": 0.0, "flood_irradiance_w_m2": 40.0})
    fl = flood_light(rig)
    part_pose = facing(fl.aim_mm, fl.e1, fl.e2)          # its z (into the plate) = the light's normal
    full = sensor_pose(rig)
    uv0 = project_points(rig, fl.aim_mm).uv_px
    u0, v0 = int(round(uv0[0])) - 4, int(round(uv0[1])) - 4
    pose = sensor_window(full, u0, v0, 9, 9)
    cp = make_pass(rig, [(plate_mesh(), "tape", 1)], pose=pose, spp=256, pixel_filter="box")
    img = cp.render(part_pose, seed=0)
    aim_px = uv0 - [u0, v0]
    got = np.interp(aim_px[0], np.arange(9), img[int(round(aim_px[1]))])   # the aim point's column
    expected = 0.55 * 40.0 / math.pi * etendue_mm2_sr(rig, pose, [aim_px])[0] * 1e-6 * electrons_per_watt(rig)
    assert got == pytest.approx(expected, rel=0.02)
    # and off: no flood light, no environment, black
    cp_off = make_pass(rig, [(plate_mesh(), "tape", 1)], pose=pose, spp=4, flood=None)
    assert cp_off.render(part_pose, seed=0).max() == 0.0


# ------------------------------------------------------------------ against Mitsuba's camera
UV_SHIFT_MM = 45.0   # texture coordinates of the plate's centre: the middle of a 60 × 60 board of 1.5 mm


def _mitsuba_reference(rig, pose, image_distance_mm, focus_mm, part_pose, square_mm, light, env, spp):
    """Mitsuba's thinlens + path (direct light) image of the same plate, its mean radiance per pixel."""
    import mitsuba as mi

    mesh = plate_mesh(300.0, 300.0, 2.0)
    v = trimesh.transform_points(mesh.vertices, part_pose)
    uv = mesh.vertices[:, :2] + UV_SHIFT_MM
    m = mi.Mesh("plate", len(v), len(mesh.faces), has_vertex_normals=False, has_vertex_texcoords=True,
                props=_bsdf_props(mi, square_mm))
    p = mi.traverse(m)
    p["vertex_positions"] = mi.Float(v.astype(np.float32).ravel())
    p["faces"] = mi.UInt32(mesh.faces.astype(np.uint32).ravel())
    p["vertex_texcoords"] = mi.Float(uv.astype(np.float32).ravel())
    p.update()
    width = pose.columns * pose.pitch_mm
    fov = math.degrees(2 * math.atan(0.5 * width / image_distance_mm))
    scene = {"type": "scene", "plate": m,
             "integrator": {"type": "path", "max_depth": 2},
             "sensor": {"type": "thinlens", "fov": fov, "fov_axis": "x",
                        "aperture_radius": 0.5 * rig.lens.focal_length_mm / rig.lens.f_number,
                        "focus_distance": focus_mm,
                        "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 0], target=[1, 0, 0], up=[0, 0, 1]),
                        "film": {"type": "hdrfilm", "width": pose.columns, "height": pose.rows,
                                 "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                        "sampler": {"type": "stratified", "sample_count": spp}}}
    if env > 0:
        scene["env"] = {"type": "constant", "radiance": {"type": "rgb", "value": [env] * 3}}
    if light is not None:
        t = np.eye(4)
        t[:3, 0], t[:3, 1], t[:3, 2], t[:3, 3] = 0.5 * light.size_mm * light.e1, 0.5 * light.size_mm * light.e2, \
            light.normal, light.centre_mm
        scene["light"] = {"type": "rectangle", "to_world": mi.ScalarTransform4f(t),
                          "emitter": {"type": "area", "radiance": {"type": "rgb",
                                                                   "value": [light.radiance_w_m2_sr] * 3}}}
    img = mi.render(mi.load_dict(scene), seed=1)
    return np.asarray(img, np.float64)[..., 2]


def _bsdf_props(mi, square_mm):
    props = mi.Properties()
    # Mitsuba's checkerboard: color0 where frac(u') > ½ equals frac(v') > ½, u' = (x + s)/(2s):
    # square (i, j) = (⌊x/s⌋ + 1, ⌊y/s⌋ + 1) black when i + j is even, as scenes.patterns draws it
    to_uv = mi.ScalarTransform4f().scale([1 / (2 * square_mm), 1 / (2 * square_mm), 1]) \
        @ mi.ScalarTransform4f().translate([square_mm, square_mm, 0])
    props["bsdf"] = mi.load_dict({"type": "twosided", "material": {"type": "diffuse", "reflectance": {
        "type": "checkerboard", "color0": {"type": "rgb", "value": [0.05] * 3},
        "color1": {"type": "rgb", "value": [0.85] * 3}, "to_uv": to_uv}}})
    return props


@pytest.mark.parametrize("lighting", ["area", "environment"])
def test_untilted_sensor_agrees_with_mitsubas_thinlens_sensor(variant, tmp_path, lighting):
    """Region flux (8 × 8 px) of a textured plate: the camera pass vs Mitsuba's thinlens + path, within 2 %."""
    import cv2

    from sim.lights import FloodLight

    rig = load_preset("paper").replace(environment={"ambient_irradiance_w_m2": 0.0})
    f, x_obj = rig.lens.focal_length_mm, 400.0
    xi = f * x_obj / (x_obj - f)
    pose = untilted_pose(rig, xi, 128, 96, 0.02)
    a = math.sqrt(0.5)                                   # the plate turned 45° in its plane, facing the camera
    part_pose = np.eye(4)
    part_pose[:3, :3] = np.column_stack([[0.0, a, a], [0.0, -a, a], [1.0, 0.0, 0.0]])
    part_pose[:3, 3] = [x_obj, 0.0, 0.0]
    light, env = None, 0.0
    if lighting == "area":
        n = np.array([1.0, 0.0, -1.0]) / math.sqrt(2)     # 45° above the plate, facing it
        e1 = np.array([0.0, 1.0, 0.0])
        light = FloodLight(np.array([x_obj - 150.0, 0.0, 150.0]), n, e1, np.cross(n, e1), 80.0, 3.0,
                           np.array([x_obj, 0.0, 0.0]))
    else:
        env = 0.5
    rig = rig.replace(environment={"ambient_irradiance_w_m2": env * math.pi})
    texture = chessboard_texture(1.5)
    mesh = plate_mesh(300.0, 300.0, 2.0)
    cp = make_pass(rig, [Textured(mesh, texture, mesh.vertices[:, :2] + UV_SHIFT_MM)], pose=pose, flood=light,
                   spp=128, pixel_filter="box")
    ours = cp.render(part_pose, seed=0).astype(np.float64)
    ref_l = _mitsuba_reference(rig, pose, xi, x_obj, part_pose, 1.5, light, env, 1024)
    uu, vv = np.meshgrid(np.arange(pose.columns), np.arange(pose.rows))
    centres = np.stack([uu.ravel(), vv.ravel()], 1)[:: 7]
    g_pix = np.interp(np.arange(pose.columns * pose.rows), np.arange(0, pose.columns * pose.rows, 7),
                      etendue_mm2_sr(rig, pose, centres, n_pix=2, n_r=4, n_phi=8)).reshape(pose.rows, pose.columns)
    ref = ref_l * g_pix * 1e-6 * electrons_per_watt(rig)
    block = lambda a: a.reshape(12, 8, 16, 8).sum(axis=(1, 3))  # noqa: E731
    side = np.concatenate([ours, np.zeros((pose.rows, 4)), ref], axis=1)
    cv2.imwrite(str(tmp_path / f"camera_pass_vs_mitsuba_{lighting}.png"),
                np.clip(side / side.max() * 255, 0, 255).astype(np.uint8))
    ratio = block(ours) / block(ref)
    assert np.abs(ratio - 1).max() < 0.02, (ratio.min(), ratio.max())
    assert block(ours).max() > 5 * block(ours).min()          # the texture is in it


# ------------------------------------------------------------------ defocus
def _slanted_edge(rig, delta_mm, filter_name, slant_deg=10.0, spp=64):
    """Oversampled edge spread of a slanted edge δ off the sheet (toward the camera), environment-lit.

    Returns x [px] (column minus the chief-ray edge column of the row), the pixel values, and the
    edge point at the window's centre (rig frame [mm]).
    """
    from sim.camera_pass import sensor_window

    g = hinge_geometry(rig)
    base = g.rig_from_sheet(600.0, 0.0)
    n_cam = toward_camera(g, base)
    c, s = math.cos(math.radians(slant_deg)), math.sin(math.radians(slant_deg))
    x_axis = c * g.propagation_dir - s * E_Z
    y_axis = np.cross(-n_cam, x_axis)                    # z = x × y = −n: into the print, away from the camera
    origin = base + delta_mm * n_cam
    part_pose = facing(origin, x_axis, y_axis)
    point = origin - 25.0 * y_axis                       # on the edge x = 0, in the half y < 0 (one polarity)
    uv_point = project_points(rig, point).uv_px
    rows, half = 64, 40
    u0, v0 = int(uv_point[0]) - half, int(uv_point[1]) - rows // 2
    pose = sensor_window(sensor_pose(rig), u0, v0, 2 * half, rows)
    texture = chessboard_texture(200.0, cols=2, rows=2, black=0.0, white=1.0)
    cp = make_pass(rig.replace(environment={"ambient_irradiance_w_m2": 1.0}),
                   [Textured(plate_mesh(400.0, 400.0, 2.0), texture)], pose=pose, spp=spp,
                   pixel_filter=filter_name)
    img = cp.render(part_pose, seed=0).astype(np.float64)
    uv = project_points(rig, origin + np.linspace(-40.0, -10.0, 301)[:, None] * y_axis).uv_px
    order = np.argsort(uv[:, 1])
    u_edge = np.interp(v0 + np.arange(rows), uv[order, 1], uv[order, 0])
    x = (u0 + np.arange(2 * half))[None, :] - u_edge[:, None]
    if img[:, :5].mean() > img[:, -5:].mean():           # dark on the left: rising edge
        img = img.max() - img
    return x.ravel(), img.ravel(), point


def _lsf_moments(x, value, half_width):
    """Mean and variance of the LSF (derivative of the binned ESF) within ±half_width of the edge."""
    bins = np.arange(-half_width, half_width + 1e-9, 0.1)
    idx = np.digitize(x, bins)
    esf = np.array([value[idx == k].mean() for k in range(1, len(bins))])
    centres = 0.5 * (bins[1:] + bins[:-1])
    esf = (esf - esf[:5].mean()) / (esf[-5:].mean() - esf[:5].mean())
    lsf = np.gradient(esf, centres)
    mean = (lsf * centres).sum() / lsf.sum()
    var = (lsf * (centres - mean) ** 2).sum() / lsf.sum()
    return mean, var


def test_knife_edge_off_the_sheet_blurs_to_the_thin_lens_circle_of_confusion(variant):
    """The edge spread of a slanted edge 8 mm off the sharp plane: 4σ = the blur's extent (rim rays) within 5 %."""
    rig = load_preset("paper")
    x, value, point = _slanted_edge(rig, 8.0, "box")
    du, _ = blur_footprint_px(rig, point)
    assert du > 8.0, du                                  # a blur of many pixels
    mean, var = _lsf_moments(x, value, 0.5 * du + 4)
    # LSF of a uniform ellipse along u: a semicircle law of half-width du/2, variance (du/2)²/4; plus the pixel's 1/12
    measured_du = 4.0 * math.sqrt(var - 1.0 / 12.0)
    assert measured_du == pytest.approx(du, rel=0.05)


@pytest.mark.parametrize("filter_name, pixel_var", [("box", 1 / 12), ("tent", 1 / 6)])
def test_knife_edge_in_the_sharp_plane_spreads_by_the_pixel_alone(variant, filter_name, pixel_var):
    """In the sheet (the sharp plane) the edge spread is the pixel's response: σ² = 1/12 (box), 1/6 (tent), 5 %."""
    rig = load_preset("paper")
    x, value, _ = _slanted_edge(rig, 0.0, filter_name)
    mean, var = _lsf_moments(x, value, 3.0)
    assert math.sqrt(var) == pytest.approx(math.sqrt(pixel_var), rel=0.05)
    assert abs(mean) < 0.02                              # the edge where the chief ray puts it


# ------------------------------------------------------------------ determinism and input
def test_same_seed_same_image_other_seed_differs(variant):
    rig = load_preset("paper").replace(environment={"flood_irradiance_w_m2": 20.0})
    g = hinge_geometry(rig)
    from sim.camera_pass import sensor_window

    pose = sensor_window(sensor_pose(rig), 300, 600, 200, 64)
    part_pose = facing(g.rig_from_sheet(600.0, 0.0), g.propagation_dir, -E_Z)
    parts = [Textured(plate_mesh(), chessboard_texture(5.0))]
    a = make_pass(rig, parts, pose=pose, spp=2).render(part_pose, seed=7)
    b = make_pass(rig, parts, pose=pose, spp=2).render(part_pose, seed=7)
    c = make_pass(rig, parts, pose=pose, spp=2).render(part_pose, seed=8)
    assert a.dtype == np.float32 and a.shape == (64, 200) and np.array_equal(a, b)  # exact: same run
    assert not np.array_equal(a, c) and a.max() > 0


def test_bad_settings_are_refused_in_one_line(variant):
    from sim.camera_pass import CameraSettings

    for kwargs in ({"spp": 0}, {"bounces": 0}, {"seed": -1}, {"pixel_filter": "gauss"}):
        with pytest.raises(RenderError) as err:
            CameraSettings(**kwargs)
        assert "\n" not in str(err.value)
    rig = load_preset("paper")
    cp = make_pass(rig, [(plate_mesh(), "tape", 1)], pose=SensorPose(sensor_pose(rig).origin_mm, np.array([0, 1.0, 0]),
                                                                      E_Z, 0.01, 4, 4), spp=1)
    for kwargs in ({"seed": -1}, {"seed": 0, "flood_scale": -1.0}, {"seed": 0, "exposure_ms": 0.0}):
        with pytest.raises(RenderError):
            cp.render(np.eye(4), **kwargs)


def test_white_furnace_more_bounces_bring_a_cavity_to_the_environments_radiance(variant):
    """Albedo 1 everywhere under a uniform environment: every surface's radiance is the environment's
    once the paths are long enough (the white furnace); one bounce leaves the cavity's floor darker."""
    rig = load_preset("paper").replace(environment={"ambient_irradiance_w_m2": math.pi})
    f, x_obj = rig.lens.focal_length_mm, 400.0
    pose = untilted_pose(rig, f * x_obj / (x_obj - f), 24, 24, 0.02)        # sees 3.5 mm of the floor's centre
    white = {"kind": "uniform", "albedo": 1.0}

    def board(lo, hi, oid):
        m = trimesh.creation.box(np.subtract(hi, lo))
        m.apply_translation(0.5 * (np.add(lo, hi)))
        return Textured(m, white, object_id=oid)

    floor = board([x_obj, -30, -30], [x_obj + 2, 30, 30], 1)
    walls = [board([x_obj - 40, -32, -30], [x_obj, -30, 30], 2), board([x_obj - 40, 30, -30], [x_obj, 32, 30], 3),
             board([x_obj - 40, -30, -32], [x_obj, 30, -30], 4), board([x_obj - 40, -30, 30], [x_obj, 30, 32], 5)]
    open_floor = make_pass(rig, [floor], pose=pose, spp=16, pixel_filter="box").render(np.eye(4), seed=1)
    one = make_pass(rig, [floor, *walls], pose=pose, spp=16, pixel_filter="box").render(np.eye(4), seed=1)
    deep = make_pass(rig, [floor, *walls], pose=pose, spp=64, bounces=24, pixel_filter="box").render(np.eye(4), seed=1)
    # the walls hide 1 − (sky's configuration factor) of the floor centre's hemisphere: F = 4·F_c(30, 30, 40)
    from sim.lights import corner_factor

    sky = 4 * corner_factor(30.0, 30.0, 40.0)
    print(f"furnace: one bounce {one.mean() / open_floor.mean():.4f} (sky factor {sky:.4f}), 24 bounces "
          f"{deep.mean() / open_floor.mean():.4f}")
    np.testing.assert_allclose(one.mean() / open_floor.mean(), sky, rtol=0.03)
    assert deep.mean() / open_floor.mean() == pytest.approx(1.0, abs=0.02)
