"""The camera's sharpening (``[chain] sharpen_amount``, ``sharpen_sigma_px``; :mod:`sim.sharpen`).

References computed here from the unsharp mask's closed forms: a Gaussian line through a
Gaussian blur is a wider Gaussian of the same area; white noise's variance through a
linear filter is its weights' squared sum.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from scheimpflug.errors import RigError
from scheimpflug.model.rig import load_preset, rig_from_dict
from sim.chain import ChainModel, apply_chain
from sim.sharpen import LUMA_WEIGHTS, unsharp_mask


def _line(width_px: float, peak: float, cols: int = 401, rows: int = 24) -> tuple[np.ndarray, np.ndarray]:
    x = np.arange(cols) - cols // 2
    return x, np.tile(peak * np.exp(-x**2 / (2 * width_px**2)), (rows, 1))


@pytest.mark.parametrize("amount, sigma", [(0.5, 8.0), (1.5, 3.0), (0.8, 15.0)])
def test_a_gaussian_line_gets_its_closed_form_peak_and_moat(amount, sigma):
    w, peak = 5.0, 50.0
    x, img = _line(w, peak)
    got = unsharp_mask(img, amount, sigma)[12].astype(np.float64)
    c = math.hypot(w, sigma)
    want = (1 + amount) * peak * np.exp(-x**2 / (2 * w**2)) - amount * peak * (w / c) * np.exp(-x**2 / (2 * c**2))
    np.testing.assert_allclose(got, want, atol=0.02 * peak)       # the discrete blur of a sampled line
    assert got[200] == pytest.approx(peak * (1 + amount * (1 - w / c)), rel=0.01)
    assert got.min() == pytest.approx(want.min(), abs=0.01 * peak) and want.min() < -0.01 * peak


def test_a_constant_image_and_amount_zero_are_unchanged():
    flat = np.full((30, 40, 3), 17.25)
    np.testing.assert_allclose(unsharp_mask(flat, 2.0, 4.0), flat, atol=1e-4)
    rng = np.random.default_rng(1)
    img = rng.uniform(0, 255, (20, 30, 3))
    np.testing.assert_array_equal(unsharp_mask(img, 0.0, 4.0), img.astype(np.float32))   # exact: copy


def test_white_noise_is_amplified_by_the_kernels_weights():
    """var' / var = (1 + a)² − 2a(1 + a)/(2πσ²) + a²/(4πσ²) (continuum weights, σ = 3 px)."""
    a, sigma = 1.0, 3.0
    noise = np.random.default_rng(7).normal(0.0, 4.0, (600, 600))
    got = np.var(unsharp_mask(noise, a, sigma)[20:-20, 20:-20]) / np.var(noise[20:-20, 20:-20])
    want = (1 + a) ** 2 - 2 * a * (1 + a) / (2 * math.pi * sigma**2) + a**2 / (4 * math.pi * sigma**2)
    assert got == pytest.approx(want, rel=0.02)


def test_colour_detail_comes_from_the_luminance():
    """Each channel gains the same a·(Y − G*Y); a grey image is the per-channel mask."""
    x, line = _line(3.0, 100.0, cols=101, rows=8)
    rgb = np.stack([line, 0.5 * line, 0.2 * line], axis=-1)
    got = unsharp_mask(rgb, 1.0, 5.0)
    luma = rgb @ np.array(LUMA_WEIGHTS)
    detail = unsharp_mask(luma, 1.0, 5.0) - luma
    for ch in range(3):
        np.testing.assert_allclose(got[..., ch] - rgb[..., ch], detail, atol=1e-3)


@pytest.mark.parametrize("amount, sigma, shape", [(-0.1, 2.0, (4, 4)), (1.0, 0.0, (4, 4)), (1.0, 2.0, (4, 4, 2))])
def test_bad_arguments_are_refused(amount, sigma, shape):
    with pytest.raises(ValueError, match="unsharp mask"):
        unsharp_mask(np.zeros(shape), amount, sigma)


def test_the_chain_floors_the_moat_at_zero_beside_a_line_on_a_dark_ground():
    """Through the whole chain (no noise, linear tone, pedestal 1 DN): the mask's moat is clipped at 0."""
    base = {"columns": 200, "rows": 40, "hinge_column": 5000.0, "adc_bits": 12, "dark_offset_dn": 0.0,
            "full_well_e": 1e6, "read_noise_e": 0.0, "quantum_efficiency": 0.5, "gain_e_per_dn": 100.0}
    chain = {"format": "png8", "black_level_dn": 1.0, "laser_qe_r": 0.5, "laser_qe_g": 0.5, "laser_qe_b": 0.5}
    plain = ChainModel.from_rig(rig_from_dict({"sensor": base, "chain": chain}))
    sharp = ChainModel.from_rig(rig_from_dict({"sensor": base, "chain": {**chain, "sharpen_amount": 1.0,
                                                                          "sharpen_sigma_px": 8.0}}))
    x = np.arange(200) - 100
    laser = np.tile(1.6e5 * np.exp(-x**2 / (2 * 4.0**2)), (40, 1))   # 1600 raw DN → 100 DN of 8 bits
    before = apply_chain(laser, None, plain)[20, :, 1].astype(float)
    after = apply_chain(laser, None, sharp)[20, :, 1].astype(float)
    # linear tone, 8 bits; ±2 DN: bilinear demosaicing interpolates a 4-px line's peak in two channels
    assert before[100] == pytest.approx(1 + 254 * 1.6e5 / (4095 * 100.0), abs=2)
    assert before[:60].min() == 1 and before[140:].min() == 1          # the pedestal
    assert after[100] == pytest.approx(before[100] + 99 * (1 - 4 / math.hypot(4, 8)), abs=3)    # a·A·(1 − w/c)
    assert np.all(after[112:125] == 0) and np.all(after[76:89] == 0)  # the moat, floored at 0
    assert after[0] == 1 and after[-1] == 1                            # far away: the pedestal


def test_the_keys_have_ranges_and_are_off_by_default():
    assert load_preset("paper").chain.sharpen_amount == 0.0
    with pytest.raises(RigError, match=r"\[chain\] sharpen_sigma_px = 0.1: out of range"):
        load_preset("paper").replace(chain={"sharpen_sigma_px": 0.1})


def test_binning_keeps_the_masks_size_on_the_sensor():
    from scheimpflug.model.binning import binned_rig

    rig = load_preset("paper").replace(chain={"sharpen_amount": 0.7, "sharpen_sigma_px": 8.0})
    assert binned_rig(rig, 4).chain.sharpen_sigma_px == pytest.approx(2.0)
    assert binned_rig(rig, 4).chain.sharpen_amount == 0.7
    assert binned_rig(rig.replace(chain={"sharpen_sigma_px": 0.5}), 4).chain.sharpen_sigma_px == 0.3


def test_the_scan_identification_fits_the_sharpening_only_when_asked():
    from scheimpflug.model.rig import rig_to_dict
    from sim.identify.scan import default_unknowns

    tables = rig_to_dict(load_preset("paper").replace(chain={"format": "jpeg"}))
    plain, sharp = default_unknowns(tables), default_unknowns(tables, sharpening=True)
    assert set(sharp) - set(plain) == {"chain.sharpen_amount", "chain.sharpen_sigma_px"}
    assert sharp["chain.sharpen_sigma_px"] == {"range": [1.0, 30.0], "prior": "log-uniform"}
    grey = rig_to_dict(load_preset("paper"))            # png16: no chain, no chain unknowns
    assert not any(k.startswith("chain.") for k in default_unknowns(grey, sharpening=True))
