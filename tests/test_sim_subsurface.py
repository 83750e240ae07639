"""Subsurface scattering (sim.subsurface) against radiative-transfer closed forms.

Reference: Chandrasekhar's H-function of isotropic scattering with single-scattering
albedo a, computed here by iterating its integral equation on a Gauss–Legendre grid,

    H(μ) = 1 / (1 − (a/2)·μ·∫₀¹ H(μ')/(μ + μ') dμ')          (Radiative Transfer, 1950, ch. V)

For a semi-infinite medium with a matched (index-1) boundary it gives

* the plane albedo at incidence μ₀:  R(μ₀) = 1 − H(μ₀)·√(1 − a);
* the bidirectional reflectance:     f_r(μ₀, μ) = a·H(μ₀)·H(μ) / (4π·(μ + μ₀)).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.rig import load_preset

pytestmark = pytest.mark.render


def h_function(albedo, n=64):
    """Chandrasekhar's H(μ) for isotropic scattering (callable), by fixed-point iteration."""
    x, w = np.polynomial.legendre.leggauss(n)
    mu, w = 0.5 * (x + 1.0), 0.5 * w
    h = np.ones(n)
    for _ in range(5000):
        h_new = 1.0 / (1.0 - 0.5 * albedo * mu * ((w * h)[None, :] / (mu[:, None] + mu[None, :])).sum(1))
        if np.max(np.abs(h_new - h)) < 1e-13:
            break
        h = h_new
    return lambda m: 1.0 / (1.0 - 0.5 * albedo * m * (w * h / (m + mu)).sum())


def test_h_function_known_values():
    # conservative scattering: H(1) = 2.9078 (Chandrasekhar, Table XIII); zeroth moment
    # ∫₀¹ H dμ = (2/a)·(1 − √(1 − a)) for any albedo (Chandrasekhar eq. V.30)
    assert h_function(1.0)(1.0) == pytest.approx(2.9078, abs=2e-3)
    x, w = np.polynomial.legendre.leggauss(40)
    for a in (0.5, 0.9):
        h = h_function(a)
        moment = sum(0.5 * wi * h(0.5 * (xi + 1)) for xi, wi in zip(x, w))
        assert moment == pytest.approx(2 / a * (1 - math.sqrt(1 - a)), rel=1e-6)


@pytest.mark.parametrize("albedo", [0.3, 0.6, 0.9, 0.99])
def test_total_reflectance_of_matched_slab_matches_chandrasekhar(variant, albedo):
    from sim.materials import Translucent
    from sim.subsurface import total_reflectance

    medium = Translucent(10.0 * albedo, 10.0 * (1.0 - albedo), 0.0, 1.0, 0.3, 0.5)
    expected = 1.0 - h_function(albedo)(1.0) * math.sqrt(1.0 - albedo)
    assert total_reflectance(medium, 200_000, max_steps=2048) == pytest.approx(expected, rel=0.03)
    oblique = 1.0 - h_function(albedo)(0.5) * math.sqrt(1.0 - albedo)
    assert total_reflectance(medium, 200_000, cos_incidence=0.5, max_steps=2048) \
        == pytest.approx(oblique, rel=0.03)


def test_hg_sampling_matches_its_density(variant, rng):
    import drjit as dr
    import mitsuba as mi

    from sim.subsurface import hg_eval, hg_sample

    g, n = 0.7, 200_000
    d = hg_sample(mi, dr, mi.Float(g), mi.Vector3f(0.0, 0.0, 1.0), mi.Float(rng.random(n)),
                  mi.Float(rng.random(n)))
    cos_t = np.asarray(d.z)
    mean_cos = float(np.mean(cos_t))
    assert mean_cos == pytest.approx(g, abs=0.01)              # ⟨cos θ⟩ = g
    counts, edges = np.histogram(cos_t, bins=20, range=(-1, 1))
    # bin probabilities from the HG cumulative distribution in cos θ (closed form)
    cdf = (1 - g * g) / (2 * g) * (1 / np.sqrt(1 + g * g - 2 * g * edges) - 1 / (1 + g))
    np.testing.assert_allclose(counts / n, np.diff(cdf), rtol=0.05)
    # and the density hg_eval integrates to one over the sphere
    mu = np.linspace(-1, 1, 20001)
    dens = 2 * math.pi * np.asarray(hg_eval(dr, mi.Float(g), mi.Float(mu)))
    assert np.trapezoid(dens, mu) == pytest.approx(1.0, rel=1e-4)


# ------------------------------------------------------------------ the renderer
def _plate_pose(rig, distance_mm, yaw_deg):
    g = hinge_geometry(rig)
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    m = np.eye(4)
    m[:3, 0] = c * g.propagation_dir + s * g.sheet_normal
    m[:3, 1] = -s * g.propagation_dir + c * g.sheet_normal
    m[:3, 2] = [0.0, 0.0, 1.0]
    m[:3, 3] = g.object_hinge_mm + distance_mm * g.propagation_dir \
        + rig.stage.calibration_table_z_mm * np.array([0.0, 0.0, 1.0])
    return m


def _thick_plate():
    plate = trimesh.creation.box([20.0, 200.0, 89.0])
    plate.apply_translation([10.0, 0.0, 44.5])      # face x = 0 toward the laser
    return plate


@pytest.mark.parametrize("yaw_deg", [0.0, 30.0, 50.0])
def test_matched_plate_image_follows_chandrasekhar_reflection_law(variant, yaw_deg):
    """Whole-image laser flux of a matched-index isotropic plate over that of a Lambertian one."""
    from scheimpflug.model.binning import binned_rig
    from sim.materials import TRANSLUCENT, MaterialSettings, Translucent
    from sim.render import Renderer, RenderSettings
    from sim.scene import SimScene
    from sim.truth import laser_origin_mm

    albedo, lambert = 0.9, 0.55
    rig = binned_rig(load_preset("paper"), 4).replace(environment={"ambient_irradiance_w_m2": 0.0})
    materials = MaterialSettings(translucent={**TRANSLUCENT, "paper": Translucent(
        10.0 * albedo, 10.0 * (1.0 - albedo), 0.0, 1.0, 0.3, 0.5)})
    pose = _plate_pose(rig, 600.0, yaw_deg)
    flux = {}
    for tag, sss in (("tape", False), ("paper", True)):
        scene = SimScene([(_thick_plate(), tag, 1)], materials, subsurface=sss)
        r = Renderer(rig.replace(twin={"subsurface": sss}), scene, RenderSettings(samples_per_row=64))
        flux[tag] = float(r.render(pose, 1).sum())
    face = -pose[:3, 0]
    centre = pose[:3, 3] + np.array([0.0, 0.0, 40.0])
    d = centre - laser_origin_mm(rig)
    mu0 = float(-d @ face / np.linalg.norm(d))
    mu = float(-centre @ face / np.linalg.norm(centre))
    h = h_function(albedo)
    f_r = albedo * h(mu0) * h(mu) / (4 * math.pi * (mu + mu0))
    assert flux["paper"] / flux["tape"] == pytest.approx(f_r / (lambert / math.pi), rel=0.03)


def test_apparent_emission_moves_forward_with_incidence(variant):
    """First moment of the light a normally-viewing camera receives, along the surface.

    Zero at normal incidence (symmetry) and growing with the angle of incidence as the
    refracted beam carries the light forward (marble, the twin's own next-event weights).
    """
    import drjit as dr
    import mitsuba as mi

    from sim.materials import TRANSLUCENT, _boundary
    from sim.subsurface import WalkMedium, hg_eval, random_walk

    m = TRANSLUCENT["marble"]
    n = 50_000
    moments = []
    for incidence in (0.0, 20.0, 40.0, 60.0):
        si = dr.zeros(mi.SurfaceInteraction3f, n)
        si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
        t = math.radians(incidence)
        si.wi = mi.Vector3f(-math.sin(t), 0.0, math.cos(t))   # light travels toward +x
        rng = mi.PCG32(size=n, initstate=mi.UInt64(5), initseq=dr.arange(mi.UInt64, n))
        bs, w = mi.load_dict(_boundary(m)).sample(mi.BSDFContext(mi.TransportMode.Importance), si,
                                                   rng.next_float32(),
                                                   mi.Point2f(rng.next_float32(), rng.next_float32()))
        acc = dr.zeros(mi.Float, 2 * 4096)
        sigma_t = m.sigma_s_per_mm + m.sigma_a_per_mm

        def nee(x, d, wt, act, u, walk, acc=acc, sigma_t=sigma_t):
            val = wt * hg_eval(dr, 0.0, -d.z) * dr.exp(-sigma_t * x.z)   # toward the normal
            slot = (walk % 4096) * 2                  # spread the sums: no atomic contention
            dr.scatter_reduce(dr.ReduceOp.Add, acc, val, slot, act)
            dr.scatter_reduce(dr.ReduceOp.Add, acc, val * x.x, slot + 1, act)

        medium = WalkMedium(mi.Float(m.sigma_s_per_mm), mi.Float(m.sigma_a_per_mm), mi.Float(0.0),
                            mi.Float(m.eta))
        random_walk(mi, dr, medium, mi.Vector3f(bs.wo.x, bs.wo.y, -bs.wo.z), w[0], rng,
                    mi.Frame3f.cos_theta(bs.wo) < 0, 256, nee)
        a = np.asarray(acc, np.float64).reshape(-1, 2).sum(0)
        moments.append(1e3 * a[1] / a[0])               # [µm]
    assert abs(moments[0]) < 10.0
    assert np.all(np.diff(moments) > 20.0)


def test_marble_stripe_is_wider_and_biased(variant):
    """The laser stripe on marble: much wider than on an opaque plate, its centre shifted."""
    from scheimpflug.model.binning import binned_rig
    from scheimpflug.stripe import extract_stripes
    from sim.render import Renderer, RenderSettings
    from sim.scene import SimScene
    from sim.truth import BruteForceCaster, stripe_truth

    rig = binned_rig(load_preset("paper"), 4).replace(environment={"ambient_irradiance_w_m2": 0.0})
    plate = _thick_plate()
    pose = _plate_pose(rig, 600.0, 0.0)
    ids = np.ones(len(plate.faces), int)
    truth = stripe_truth(rig, plate.vertices, plate.faces, ids, pose, pose,
                         BruteForceCaster(plate.vertices @ pose[:3, :3].T + pose[:3, 3], plate.faces, ids))
    width, bias = {}, {}
    for sss in (False, True):
        scene = SimScene([(plate, "marble", 1)], subsurface=sss)
        r = Renderer(rig.replace(twin={"subsurface": sss}), scene,
                     RenderSettings(samples_per_row=64, subsurface_max_steps=1024))
        img = r.render(pose, 1).astype(np.float64)
        rows = np.nonzero(np.isfinite(truth.stripe_u))[0][10:-10]
        cols = np.arange(img.shape[1])
        prof = img[rows]
        mean = (prof * cols).sum(1) / prof.sum(1)
        width[sss] = np.median(np.sqrt((prof * (cols - mean[:, None]) ** 2).sum(1) / prof.sum(1)))
        p = extract_stripes(img, "cog", window_px=7)
        ok = np.isin(p.rows, rows)
        bias[sss] = np.median(p.u[ok] - truth.stripe_u[p.rows[ok]])
    g = hinge_geometry(rig)
    distance = float(g.distance_from_column(np.nanmedian(truth.stripe_u)))
    shift_mm = (bias[True] - bias[False]) * distance**2 / abs(g.F2_px_mm)   # along the sheet
    assert width[True] > 5 * width[False]
    assert abs(bias[False]) < 0.02
    assert abs(shift_mm) > 0.02
