"""The camera chain of real scanners (issue 35, item 4) against closed forms and known truth.

Each reference is computed here, independently of ``sim``: the camera equation and the
transfer functions' published formulas (uniform patch), the Cauchy line spread of the
configured tail (halo), the spill rule worked by hand (blooming), an independent encoder
(JPEG), libjpeg's table scaling (quality).
"""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np
import pytest

from scheimpflug.errors import RigError
from scheimpflug.model.chain import BAYER_PATTERNS, chain_is_on
from scheimpflug.model.rig import Rig, load_preset, rig_from_dict
from sim.blooming import bloom_columns, spill_length_px
from sim.chain import ChainModel, apply_chain, encode_frame, expected_charge, raw_frame
from sim.glare import apply_glare, glare_reach
from sim.jpeg import encode_jpeg, estimate_quality, jpeg_quality_of_file
from sim.sensor import frame_rng

FABSCAN = Path(__file__).resolve().parents[1].parent / "shared" / "realdata" / "fabscan" / "scan-2_1"

H_PLANCK, C_LIGHT = 6.62607015e-34, 299792458.0       # SI, exact (2019 SI)


def _rig(chain: dict, **sensor) -> Rig:
    base = {"columns": 64, "rows": 48, "hinge_column": 5000.0, "adc_bits": 12, "dark_offset_dn": 64.0,
            "full_well_e": 10000.0, "read_noise_e": 2.0, "quantum_efficiency": 0.5}
    return rig_from_dict({"sensor": {**base, **sensor}, "chain": {"format": "png8", **chain}})


# ------------------------------------------------------------------ uniform patch


def _reference_tone(x: float, curve: str, gamma: float) -> float:
    x = min(max(x, 0.0), 1.0)
    if curve == "srgb":           # IEC 61966-2-1
        return 12.92 * x if x <= 0.0031308 else 1.055 * x ** (1 / 2.4) - 0.055
    if curve == "bt709":          # ITU-R BT.709-6, OETF
        return 4.5 * x if x < 0.018 else 1.099 * x**0.45 - 0.099
    return x ** (1 / gamma)


def _photons_per_pixel(radiance_w_m2_sr: float, wavelength_nm: float, f_number: float, pitch_um: float,
                       exposure_ms: float) -> float:
    """Camera equation on axis, object far: E = π L / (4 N²); photons = E·p²·t / (h c / λ)."""
    irradiance = math.pi * radiance_w_m2_sr / (4 * f_number**2)
    energy_j = irradiance * (pitch_um * 1e-6) ** 2 * exposure_ms * 1e-3
    return energy_j / (H_PLANCK * C_LIGHT / (wavelength_nm * 1e-9))


@pytest.mark.parametrize("pattern", BAYER_PATTERNS)
@pytest.mark.parametrize("curve,gamma", [("gamma", 1.0), ("gamma", 2.2), ("srgb", 1.0), ("bt709", 1.0)])
def test_a_uniform_patch_gives_response_times_gain_through_the_tone_curve(pattern, curve, gamma):
    qe_laser, qe_flood = (0.45, 0.06, 0.03), (0.30, 0.42, 0.33)
    chain = {"bayer_pattern": pattern, "tone_curve": curve, "gamma": gamma, "analogue_gain": 2.0,
             "black_level_dn": 4.0, **dict(zip(("laser_qe_r", "laser_qe_g", "laser_qe_b"), qe_laser)),
             **dict(zip(("flood_qe_r", "flood_qe_g", "flood_qe_b"), qe_flood))}
    rig = _rig(chain)
    model = ChainModel.from_rig(rig)
    # a patch of spectral radiance 3 W/(m² sr) at 650 nm (laser) and 1 of flood light, f/2, 1.12 µm, 2 ms
    laser_ph = _photons_per_pixel(3.0, 650.0, 2.0, 1.12, 2.0)
    flood_ph = _photons_per_pixel(1.0, 550.0, 2.0, 1.12, 2.0)
    qe_s = rig.sensor.quantum_efficiency
    shape = (rig.sensor.rows, rig.sensor.columns)
    rgb = apply_chain(np.full(shape, qe_s * laser_ph), np.full(shape, qe_s * flood_ph), model, rng=None)
    g = rig.sensor.full_well_e / (4095 - 64.0)                    # e⁻/DN: full well at full scale
    for c in range(3):
        n_e = qe_laser[c] * laser_ph + qe_flood[c] * flood_ph
        x = 2.0 * n_e / g / (4095 - 64.0)
        want = 4.0 + 251.0 * _reference_tone(x, curve, gamma)
        got = rgb[1:-1, 1:-1, c].astype(float)
        assert np.abs(got - want).max() <= 1.0, (c, want, got.min(), got.max())
    assert 0.05 < 2.0 * qe_laser[0] * laser_ph / g / 4031 < 0.95        # the patch is inside the linear range


def test_the_noisy_patch_mean_is_the_closed_form_and_a_seed_repeats():
    rig = _rig({"laser_qe_r": 0.5, "laser_qe_g": 0.5, "laser_qe_b": 0.5})
    model = ChainModel.from_rig(rig)
    light = np.full((rig.sensor.rows, rig.sensor.columns), 2500.0)
    a = apply_chain(light, None, model, frame_rng(7, 0))
    assert np.array_equal(a, apply_chain(light, None, model, frame_rng(7, 0)))   # exact: same run
    assert not np.array_equal(a, apply_chain(light, None, model, frame_rng(8, 0)))
    want = 255.0 * 2500.0 / (10000.0 / 4031.0) / 4031.0           # linear tone, gain 1, no pedestal
    assert abs(a[1:-1, 1:-1].mean() - want) < 0.5


# ------------------------------------------------------------------ veiling glare


def _segment_spread(x: np.ndarray, y1: float, y2: float, s: float) -> np.ndarray:
    """∫_{y1}^{y2} K(x, y) dy for K = s / (2π (s² + r²)^{3/2}) (closed form)."""
    a2 = s * s + x * x
    return s / (2 * np.pi * a2) * (y2 / np.sqrt(a2 + y2**2) - y1 / np.sqrt(a2 + y1**2))


def _pixel_mean(f, x):
    """Simpson's rule over the pixel [x − ½, x + ½]."""
    return (f(x - 0.5) + 4 * f(x) + f(x + 0.5)) / 6


def test_the_halo_across_a_thin_line_is_the_configured_point_spread():
    rows, cols, s, eta, power = 400, 600, 12.0, 0.08, 1e4
    line = np.zeros((rows, cols))
    line[:, 100] = power
    out = apply_glare(line, eta, s).astype(np.float64)
    x = np.arange(2, glare_reach(cols, s) + 1)                 # the convolution's reach: 240 px
    assert x[-1] == 240
    r = rows // 2
    want = eta * power * _pixel_mean(lambda u: _segment_spread(u, -r - 0.5, rows - r - 0.5, s), x)
    ratio = out[r, 100 + x] / want
    assert np.all(np.abs(ratio - 1) < 0.05), (ratio.min(), ratio.max())
    # far from the ends the line is as good as infinite: the Cauchy profile (s/π)/(s² + x²)
    cauchy = eta * power * (s / np.pi) / (s**2 + 25.0**2)
    assert abs(out[r, 125] / cauchy - 1) < 0.05
    assert out[r, 100] == pytest.approx((1 - eta) * power + eta * power * _segment_spread(
        np.array(0.0), -r - 0.5, rows - r - 0.5, s) * 1.0, rel=0.05)


def test_the_halo_survives_the_chain_before_quantisation():
    """Through glare, mosaic (equal responses), shot-noise-free charge and a 16-bit ADC: log signal vs distance."""
    s, eta = 10.0, 0.05                             # 10 px of 2.5 µm: glare_scale_um = 25
    rig = _rig({"glare_fraction": eta, "glare_scale_um": 25.0}, columns=300, rows=200, adc_bits=16,
               dark_offset_dn=0.0, full_well_e=1e6, gain_e_per_dn=0.01, pixel_pitch_um=2.5)
    model = ChainModel.from_rig(rig)
    laser = np.zeros((200, 300))
    laser[:, 50] = 0.5 * 50000.0                    # the render's electrons at QE 0.5 → 0.75 × 50000 in each channel
    raw = raw_frame(expected_charge(laser, None, model), model, rng=None).astype(np.float64)
    x = np.arange(3, 150)
    want = eta * 0.75 * 50000.0 / 0.01 * _pixel_mean(lambda u: _segment_spread(u, -100.5, 99.5, s), x)
    got = raw[100, 50 + x]
    assert np.all(np.abs(np.log(got) - np.log(want)) < 0.05), np.abs(np.log(got / want)).max()


# ------------------------------------------------------------------ blooming


def test_a_saturated_pixel_blooms_along_its_column_by_the_rule():
    w, b = 1000.0, 200.0
    col = np.full((41, 3), b)
    col[20, 1] = w + 5600.0                        # 2800 e⁻ each way: 3.5 pixels of room (800 e⁻) each side
    out = bloom_columns(col, w, 1.0)
    assert out.sum() == pytest.approx(col.sum(), abs=1e-6)                      # charge conserved
    assert spill_length_px(5600.0, w, b, 1.0) == 4
    np.testing.assert_allclose(out[15:26, 1], [200, 600] + [1000] * 7 + [600, 200])    # ±3 full, ±4 half
    np.testing.assert_array_equal(out[:, [0, 2]], col[:, [0, 2]])   # exact: copy (other columns untouched)
    half = bloom_columns(col, w, 0.5)                                          # half drained
    assert half.sum() == pytest.approx(col.sum() - 0.5 * 5600.0)
    np.testing.assert_allclose(half[17:24, 1], [200, 800, 1000, 1000, 1000, 800, 200])   # 1400 e⁻ each way
    off = bloom_columns(col, w, 0.0)
    assert off[20, 1] == w and off.sum() == pytest.approx(col.sum() - 5600.0)   # today's full-well clip


def test_spill_past_the_sensor_edge_is_lost():
    col = np.zeros((5, 1))
    col[0, 0] = 10000.0
    out = bloom_columns(col, 1000.0, 1.0)
    assert out[:, 0].tolist() == [1000.0] * 5                 # the downward half fills the column …
    assert out.sum() == 5000.0                                 # … the upward half left at row 0


def test_a_saturated_stripe_blooms_in_the_chain():
    rig = _rig({"bloom_spill_fraction": 1.0, "laser_qe_r": 0.5, "laser_qe_g": 0.5, "laser_qe_b": 0.5},
               gain_e_per_dn=10000.0 / 4031.0)
    model = ChainModel.from_rig(rig)
    laser = np.zeros((48, 64))
    laser[24, 10] = 10000.0 + 2 * 3 * 10000.0      # 3 full wells of spill each way over an empty column
    raw = raw_frame(expected_charge(laser, None, model), model, rng=None)
    np.testing.assert_array_equal(raw[20:29, 10], [64] + [4095] * 7 + [64])   # exact: integers (ADC codes)


# ------------------------------------------------------------------ JPEG


def _decode(data: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"), dtype=np.float64)


@pytest.mark.parametrize("quality", [50, 75, 95])
def test_jpeg_decodes_within_the_encoders_own_error(quality):
    import cv2

    rig = _rig({"format": "jpeg", "jpeg_quality": quality, "jpeg_subsampling": "4:2:0", "glare_fraction": 0.05,
                "laser_qe_r": 0.6, "laser_qe_g": 0.1, "laser_qe_b": 0.05, "tone_curve": "srgb"},
               columns=160, rows=120)
    model = ChainModel.from_rig(rig)
    laser = np.zeros((120, 160))
    laser[:, 70:74] = 8000.0
    rgb = apply_chain(laser, np.full((120, 160), 300.0), model, frame_rng(1, 0))
    ours = _decode(encode_frame(rgb, model.chain)) - rgb
    ok, ref = cv2.imencode(".jpg", rgb[..., ::-1].copy(), [cv2.IMWRITE_JPEG_QUALITY, quality,
                                                            cv2.IMWRITE_JPEG_SAMPLING_FACTOR,
                                                            cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420])
    theirs = _decode(ref.tobytes()) - rgb
    rms = lambda d: float(np.sqrt(np.mean(d**2)))   # noqa: E731
    assert rms(ours) <= 1.05 * rms(theirs) + 0.05, (rms(ours), rms(theirs))
    assert np.abs(ours).max() <= np.abs(theirs).max() + 2


def test_quality_estimation_recovers_q_from_pillow_and_opencv_files():
    import cv2
    from PIL import Image

    rgb = (np.random.default_rng(0).random((32, 32, 3)) * 255).astype(np.uint8)
    for q in range(1, 101):
        pil = estimate_quality(Image.open(io.BytesIO(encode_jpeg(rgb, q))).quantization)
        ok, data = cv2.imencode(".jpg", rgb, [cv2.IMWRITE_JPEG_QUALITY, q])
        ocv = estimate_quality(Image.open(io.BytesIO(data.tobytes())).quantization)
        assert (pil.quality, pil.exact, ocv.quality, ocv.exact) == (q, True, q, True)


def test_a_camera_of_its_own_tables_is_not_called_exact():
    from sim.jpeg import STD_CHROMINANCE, STD_LUMINANCE, ijg_table

    tables = {0: ijg_table(STD_LUMINANCE, 80).copy(), 1: ijg_table(STD_CHROMINANCE, 80)}
    tables[0][5] += 3
    est = estimate_quality(tables)
    assert (est.quality, est.exact, est.mismatch) == (80, False, 3)


@pytest.mark.skipif(not FABSCAN.is_dir(), reason="the FabScan frames (../shared/realdata/fabscan/scan-2_1) are absent")
def test_the_fabscan_frames_are_quality_95_and_the_pi_preset_says_so():
    qualities = {jpeg_quality_of_file(p) for p in sorted(FABSCAN.glob("*.jpg"))}
    assert len(qualities) == 1
    (q,) = qualities
    assert q.exact and q.quality == 95
    assert rig_from_dict({"chain": {"preset": "raspberry_pi_v2"}}).chain.jpeg_quality == q.quality


# ------------------------------------------------------------------ the table: defaults, presets, bad input


def test_the_default_chain_is_off_and_a_preset_fills_only_what_is_left_out():
    assert not chain_is_on(Rig().chain) and not chain_is_on(load_preset("paper").chain)
    assert rig_from_dict({}) == rig_from_dict({"chain": {}})
    pi = rig_from_dict({"chain": {"preset": "raspberry_pi_v2", "jpeg_quality": 80}}).chain
    assert (pi.format, pi.jpeg_quality, pi.jpeg_subsampling) == ("jpeg", 80, "4:2:0")
    again = load_preset("paper").replace(chain={"glare_fraction": 0.0})
    assert again.chain.format == "png16"


@pytest.mark.parametrize("chain,needle", [
    ({"preset": "nikon_d850"}, r"\[chain\] preset = 'nikon_d850': unknown camera \(known: 'none', 'raspberry_pi_v2'"),
    ({"bayer_pattern": "RGBG"}, r"\[chain\] bayer_pattern = 'RGBG': must be one of 'RGGB', 'BGGR', 'GRBG', 'GBRG'"),
    ({"format": "tiff"}, r"\[chain\] format = 'tiff': must be one of"),
    ({"demosaic": "vng"}, r"\[chain\] demosaic = 'vng': must be one of 'bilinear', 'edge_aware'"),
    ({"jpeg_quality": 0}, r"\[chain\] jpeg_quality = 0: out of range: must be in \[1, 100\]"),
    ({"glare_fraction": 1.0}, r"\[chain\] glare_fraction = 1.0: out of range: must be in \[0, 0.99\]"),
    ({"analogue_gain": 0.5}, r"\[chain\] analogue_gain = 0.5: out of range"),
    ({"laser_qe_r": 1.2}, r"\[chain\] laser_qe_r = 1.2: out of range"),
    ({"gamma": "2.2"}, r"\[chain\] gamma = '2.2': must be a number"),
    ({"sharpness": 1}, r"\[chain\] unknown key 'sharpness'"),
])
def test_bad_chain_input_is_one_typed_error_naming_the_key(chain, needle):
    with pytest.raises(RigError, match=needle) as err:
        rig_from_dict({"chain": chain})
    assert "\n" not in str(err.value)


def test_a_dataset_refuses_the_camera_chain_in_one_line(tmp_path):
    from scheimpflug.errors import DatasetError
    from sim.dataset.spec import load_spec

    (tmp_path / "pi.toml").write_text('[chain]\npreset = "raspberry_pi_v2"\n')
    spec = tmp_path / "spec.toml"
    spec.write_text('[dataset]\nseed = 1\nsamples = 1\n[rig]\nfile = "pi.toml"\n'
                    '[scenario]\nkind = "rotary"\npart = "sphere"\nstep_deg = 90.0\nframes = 2\nbinning = 4\n')
    with pytest.raises(DatasetError, match=r"\[chain\] format = 'jpeg': a dataset stores 16-bit grey frames only"):
        load_spec(spec)


def test_read_out_adds_gaussian_read_noise_through_the_analogue_gain():
    from sim.sensor import SensorModel, read_out

    model = SensorModel(full_well_e=1e5, read_noise_e=5.0, dark_offset_dn=100.0, gain_e_per_dn=1.0, adc_bits=16)
    dn = read_out(np.full((400, 250), 1000.0), model, frame_rng(3, 0), analogue_gain=2.0).astype(float)
    assert dn.mean() == pytest.approx(100.0 + 2.0 * 1000.0, abs=0.1)          # b + G·n/g
    assert dn.var() == pytest.approx((2.0 * 5.0) ** 2 + 1 / 12, rel=0.02)      # (G σ/g)² + rounding
    clipped = read_out(np.full((2, 2), 1e5), model, None, analogue_gain=4.0)
    assert clipped.tolist() == [[65535, 65535]] * 2                           # the ADC clips before the well


def test_a_tone_table_maps_the_patch_by_straight_lines():
    table = "0:0, 0.1:0.4, 0.5:0.8, 1:1"
    rig = _rig({"tone_curve": "table", "tone_table": table, "laser_qe_r": 0.5, "laser_qe_g": 0.5, "laser_qe_b": 0.5},
               gain_e_per_dn=1.0, full_well_e=1e5)
    for n_e, want_y in ((403.1, 0.4), (2015.5, 0.4 + 0.4 * (0.5 - 0.1) / 0.4), (1209.3, 0.4 + 0.4 * 0.2 / 0.4)):
        x = n_e / 4031.0                     # linear signal: gain 1 e⁻/DN over 4031 DN above black
        want = 255.0 * (0.4 * x / 0.1 if x <= 0.1 else 0.4 + (0.8 - 0.4) * (x - 0.1) / 0.4)
        assert want == pytest.approx(255.0 * want_y, abs=0.6)
        rgb = apply_chain(np.full((8, 8), n_e), None, ChainModel.from_rig(rig), rng=None)
        assert np.abs(rgb[1:-1, 1:-1].astype(float) - want).max() <= 1.0


@pytest.mark.parametrize("table,needle", [("0:0, 1", "at least two points"), ("0:0; 1:1", "points x:y"),
                                          ("0.1:0, 1:1", "increase strictly from 0 to 1"),
                                          ("0:0, 1:1.5", r"in \[0, 1\]")])
def test_a_bad_tone_table_is_one_error_naming_it(table, needle):
    with pytest.raises(RigError, match=r"\[chain\] tone_table = .*" + needle):
        rig_from_dict({"chain": {"tone_curve": "table", "tone_table": table}})


@pytest.mark.parametrize("pattern", BAYER_PATTERNS)
def test_both_demosaicings_keep_a_uniform_colour(pattern):
    from sim.mosaic import channel_map, demosaic

    colour = np.array([3000, 700, 150], dtype=np.uint16)
    raw = colour[channel_map((12, 16), pattern)]
    for method in ("bilinear", "edge_aware"):
        rgb = demosaic(raw, pattern, method)
        assert np.abs(rgb[2:-2, 2:-2].astype(int) - colour).max() <= 1, method   # 1 DN: rounding
