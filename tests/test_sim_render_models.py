"""Light-sheet model, speckle, materials and variant selection (pure functions, fast)."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from scipy.integrate import quad

from scheimpflug.errors import MeshError, RenderError
from scheimpflug.model.rig import load_preset
from sim import lightsheet as ls
from sim import variant as var
from sim.materials import MaterialSettings, bsdf_dict, channel_for_wavelength


@pytest.fixture
def sheet():
    return ls.light_sheet(load_preset("paper"))


def test_beam_width_law(sheet):
    assert ls.beam_half_width_mm(sheet, sheet.waist_distance_mm) == pytest.approx(0.150)
    far = sheet.waist_distance_mm + 1e6
    assert ls.beam_half_width_mm(sheet, far) / 1e6 == pytest.approx(1.5e-3, rel=1e-6)
    # 100 mm from the waist: √(0.15² + 0.15²)
    assert ls.beam_half_width_mm(sheet, 540.0) == pytest.approx(0.15 * math.sqrt(2))


def test_fan_power_is_conserved(sheet):
    half = 0.5 * sheet.fan_full_rad + 10 * sheet.edge_sigma_rad
    total, _ = quad(lambda a: ls.radiant_intensity_w_per_rad(sheet, a), -half, half, limit=200)
    assert total == pytest.approx(sheet.power_w, rel=1e-9)
    # flat top, half power at the nominal edge, 10–90 % over fan_edge_deg
    g = ls.fan_profile(sheet, np.radians([0.0, 20.0]))
    np.testing.assert_allclose(g, [1.0, 0.5], atol=1e-12)
    e = math.radians(1.0)
    np.testing.assert_allclose(ls.fan_profile(sheet, np.radians(20.0) + np.array([-e / 2, e / 2])),
                               [0.9, 0.1], atol=1e-9)


def test_irradiance_integrates_to_power_across_thickness(sheet):
    """∫ E do at fixed r, times r dα, is I(α)dα: the Gaussian thickness is normalised."""
    r = 500.0
    s = 0.5 * ls.beam_half_width_mm(sheet, r)
    o = np.linspace(-8 * s, 8 * s, 4001)
    p = sheet.origin_mm + r * sheet.prop_dir + o[:, None] * sheet.normal
    line = np.trapezoid(ls.irradiance_w_mm2(sheet, p), o) * r
    assert line == pytest.approx(float(ls.radiant_intensity_w_per_rad(sheet, 0.0)), rel=1e-6)


def test_ray_ensemble_reproduces_gaussian_beam(sheet, rng):
    """Offsets x0 + a(r − r_w) drawn through conditional_angle at r_ref have std w(r)/2 at any r."""
    r_ref = 500.0
    s_ref, k, sig_a = ls.conditional_angle(sheet, r_ref)
    delta = s_ref * rng.standard_normal(400_000)
    a = k * delta + sig_a * rng.standard_normal(delta.size)
    for r in (0.0, 300.0, 640.0, 900.0):
        offset = delta + a * (r - r_ref)
        assert offset.std() == pytest.approx(0.5 * ls.beam_half_width_mm(sheet, r), rel=0.01)
    assert a.std() == pytest.approx(0.5 * sheet.divergence_rad, rel=0.01)


def test_speckle_statistics():
    # grain of 6 px: pattern correlated over pixels, pixel-value contrast C/√M
    shape, grain = (512, 512), 6.0
    pat = ls.speckle_pattern(shape, 1.0, grain, seed=1)
    a_c = 4 / math.pi * (grain / 1.22) ** 2
    assert pat.mean() == pytest.approx(1.0, abs=0.02)
    assert pat.std() == pytest.approx(1.0 / math.sqrt(1 + 1 / a_c), rel=0.05)
    assert pat.min() >= 0
    np.testing.assert_array_equal(pat, ls.speckle_pattern(shape, 1.0, grain, seed=1))  # exact: same run
    assert not np.array_equal(pat, ls.speckle_pattern(shape, 1.0, grain, seed=2))
    # sub-pixel grain (paper rig: ≈ 0.6 px): white, contrast strongly reduced by the pixel
    small = ls.speckle_pattern(shape, 0.8, 0.6, seed=3)
    assert small.std() == pytest.approx(0.8 / math.sqrt(1 + 1 / (4 / math.pi * (0.6 / 1.22) ** 2)),
                                        rel=0.05)
    np.testing.assert_array_equal(ls.speckle_pattern(shape, 0.0, grain, seed=1), 1.0)  # exact: copy
    assert ls.speckle_grain_um(450.0, 5.6, 0.1) == pytest.approx(1.22 * 0.45 * 5.6 * 1.1)


def test_visible_fan_interval(sheet):
    pts = sheet.origin_mm + np.array([[500.0, 0, 30.0], [800.0, 0, -60.0]]) @ np.stack(
        [sheet.prop_dir, sheet.normal, sheet.up])
    lo, hi = ls.visible_fan_interval(sheet, pts, 0.0)
    assert (lo, hi) == pytest.approx((math.atan2(-60, 800), math.atan2(30, 500)))
    assert ls.visible_fan_interval(sheet, np.full((1, 3), np.nan), 0.0)[1] > sheet.fan_full_rad / 2


def test_materials():
    d = bsdf_dict("cardboard")
    assert d["type"] == "twosided" and d["material"]["type"] == "diffuse"
    m = bsdf_dict("metal", MaterialSettings(metal_alpha=0.2))
    assert m["material"]["alpha"] == 0.2 and m["material"]["type"] == "roughconductor"
    assert bsdf_dict("knurled-metal")["material"]["alpha"] > m["material"]["alpha"]
    with pytest.raises(MeshError, match="unknown material 'glass'"):
        bsdf_dict("glass")
    with pytest.raises(ValueError, match="albedo"):
        MaterialSettings(tape_albedo=1.5)
    assert [channel_for_wavelength(w) for w in (405, 450, 520, 650)] == [2, 2, 1, 0]


@pytest.mark.parametrize("name, version", [
    ("/usr/lib/x86_64-linux-gnu/libLLVM-14.so", 14), ("libLLVM.so.19.1", 19),
    ("libLLVM-15.so.1", 15), ("/usr/lib/llvm-17/lib/libLLVM.so.1", 17),
    ("libLLVM.17.dylib", 17), ("libfoo.so", None)])
def test_llvm_version_from_path(name, version):
    assert var.llvm_version_from_path(name) == version


def test_select_variant_falls_back_without_llvm17(monkeypatch):
    chosen = []
    monkeypatch.delenv("SCHEIMPFLUG_VARIANT", raising=False)
    monkeypatch.setattr(var, "find_libllvm", lambda: ("/usr/lib/libLLVM-15.so", 15))
    monkeypatch.setattr(var, "_set", lambda v: chosen.append(v) or v)
    with pytest.warns(RuntimeWarning, match="version 15.*falling back to scalar_rgb"):
        assert var.select_variant() == "scalar_rgb"
    monkeypatch.setattr(var, "find_libllvm", lambda: (None, None))
    with pytest.warns(RuntimeWarning, match="no libLLVM"):
        var.select_variant()
    monkeypatch.setattr(var, "find_libllvm", lambda: ("/usr/lib/libLLVM-19.so", 19))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert var.select_variant() == "llvm_ad_rgb"
    monkeypatch.setenv("SCHEIMPFLUG_VARIANT", "scalar_rgb")
    assert var.select_variant() == "scalar_rgb"
    assert chosen == ["scalar_rgb", "scalar_rgb", "llvm_ad_rgb", "scalar_rgb"]
    monkeypatch.setenv("SCHEIMPFLUG_VARIANT", "no_such_variant")
    with pytest.raises(RenderError, match="not available"):
        var.select_variant()


def test_render_settings_validation():
    from sim.render import RenderSettings

    with pytest.raises(RenderError, match="pixel_filter"):
        RenderSettings(pixel_filter="gauss")
    with pytest.raises(RenderError, match="multiple of 4"):
        RenderSettings(pilot_block=6)
    with pytest.raises(RenderError, match="samples_per_row"):
        RenderSettings(samples_per_row=0)
