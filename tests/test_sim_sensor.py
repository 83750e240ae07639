"""Sensor model: flat-field statistics against shot + read + quantisation noise, seeding."""

import hashlib

import numpy as np
import pytest
from scipy import stats

from scheimpflug.model.rig import load_preset
from sim import sensor as sensor_module
from sim.sensor import (
    SensorModel,
    apply_sensor,
    conversion_gain_e_per_dn,
    frame_rng,
    full_scale_dn,
    poisson_counts,
)


@pytest.fixture(scope="module")
def rig():
    return load_preset("paper")


def _flat(rig, electrons, shape=(1000, 1000), seed=3, backend=None, **sensor):
    r = rig.replace(sensor=sensor) if sensor else rig
    model = SensorModel.from_rig(r)
    frame = apply_sensor(np.full(shape, electrons, np.float32), model, frame_rng(seed, 0), backend=backend)
    return model, frame.astype(np.float64)


def test_default_gain_maps_full_well_plus_offset_to_full_scale(rig):
    s = rig.sensor
    g = conversion_gain_e_per_dn(s)
    assert s.dark_offset_dn + s.full_well_e / g == pytest.approx(full_scale_dn(s), rel=1e-12)
    assert full_scale_dn(s) == 4095


@pytest.mark.parametrize("electrons, sensor", [
    (5000.0, {}),                                        # paper sensor, ~7.8 e-/DN
    (150.0, {"gain_e_per_dn": 1.0, "read_noise_e": 3.0}),  # unit gain: quantisation matters
    (40.0, {"gain_e_per_dn": 0.5, "read_noise_e": 2.0}),   # gain < 1 e-/DN
    (3.0, {"gain_e_per_dn": 0.25, "read_noise_e": 0.5}),   # small λ: CDF-inversion path
    (23.5, {"gain_e_per_dn": 0.5, "read_noise_e": 1.0}),   # just below the path switch
])
@pytest.mark.parametrize("backend", ["drjit", "numba"])
def test_flat_field_mean_and_variance(rig, electrons, sensor, backend):
    # 1e6 pixels: the relative standard error of a sample variance is sqrt(2/n) = 0.14 %,
    # well inside the 2 % acceptance.
    model, dn = _flat(rig, electrons, backend=backend, **sensor)
    g = model.gain_e_per_dn
    mean_expected = model.dark_offset_dn + electrons / g
    var_expected = (electrons + model.read_noise_e**2) / g**2 + 1 / 12
    assert dn.mean() == pytest.approx(mean_expected, rel=0.02)
    assert dn.var() == pytest.approx(var_expected, rel=0.02)
    assert model.variance_dn2(electrons) == pytest.approx(var_expected, rel=1e-12)


@pytest.mark.parametrize("backend", ["drjit", "numba"])
def test_dark_frame_reads_offset_and_read_noise(rig, backend):
    model, dn = _flat(rig, 0.0, backend=backend, gain_e_per_dn=1.0, read_noise_e=4.0, dark_offset_dn=100.0)
    assert dn.mean() == pytest.approx(100.0, abs=0.02)
    assert dn.var() == pytest.approx(16 + 1 / 12, rel=0.02)


def test_saturation_and_adc_clip(rig):
    model, dn = _flat(rig, 1e6, shape=(100, 100))       # 30× the full well
    # full well maps to full scale; read noise can only pull a full pixel down
    assert dn.max() == 4095
    assert np.mean(dn == 4095) > 0.4
    assert dn.min() >= 4095 - 6 * model.read_noise_e / model.gain_e_per_dn
    _, dn = _flat(rig, 1e6, shape=(10, 10), adc_bits=8, dark_offset_dn=0.0, gain_e_per_dn=1.0)
    assert dn.max() == 255                               # ADC clip below the full well


def test_dtype_and_raw_value_storage(rig):
    model = SensorModel.from_rig(rig)
    frame = apply_sensor(np.full((4, 5), 1000.0, np.float32), model, frame_rng(0, 0))
    assert frame.dtype == np.uint16 and frame.shape == (4, 5)
    assert frame.max() <= 4095                           # raw 12-bit value, not left-shifted


def test_same_seed_bit_identical_other_seed_or_frame_differs(rig):
    model = SensorModel.from_rig(rig)
    lam = np.random.default_rng(0).uniform(0, 3000, (64, 48)).astype(np.float32)

    def digest(seed, frame):
        return hashlib.sha256(apply_sensor(lam, model, frame_rng(seed, frame)).tobytes()).hexdigest()

    assert digest(7, 3) == digest(7, 3)
    assert digest(7, 3) != digest(8, 3)
    assert digest(7, 3) != digest(7, 4)


def test_bad_input(rig):
    model = SensorModel.from_rig(rig)
    with pytest.raises(ValueError, match="rows, columns"):
        apply_sensor(np.zeros(5), model, frame_rng(0, 0))
    with pytest.raises(ValueError, match=">= 0"):
        apply_sensor(np.full((2, 2), np.nan), model, frame_rng(0, 0))
    with pytest.raises(ValueError, match=">= 0"):
        apply_sensor(np.full((2, 2), -1.0), model, frame_rng(0, 0))


@pytest.mark.parametrize("lam", [0.05, 2.5, 9.9, 10.0, 30.0, 150.0, 3000.0])
@pytest.mark.parametrize("backend", ["drjit", "numba"])
def test_poisson_counts_follow_the_pmf(lam, backend):
    # both branches: CDF inversion (λ < 10) and PTRS + fallback (λ ≥ 10)
    counts = poisson_counts(np.full(400_000, lam, np.float32), frame_rng(11, 0), backend=backend).astype(int)
    k = np.arange(counts.max() + 1)
    observed = np.bincount(counts, minlength=len(k))
    expected = stats.poisson.pmf(k, np.float32(lam)) * counts.size
    keep = expected > 50                       # bins with enough counts for a chi-square
    rest = counts.size - observed[keep].sum(), counts.size - expected[keep].sum()
    chi2 = np.sum((observed[keep] - expected[keep]) ** 2 / expected[keep])
    chi2 += (rest[0] - rest[1]) ** 2 / max(rest[1], 1.0)   # pooled tail bins
    # p > 1e-4: a correct sampler fails this 1 time in 10,000
    assert stats.chi2.sf(chi2, keep.sum()) > 1e-4
    assert np.all(counts >= 0)
    assert counts.mean() == pytest.approx(lam, rel=5 * np.sqrt(1 / (lam * counts.size)) + 1e-12,
                                          abs=1e-3)


def test_inversion_branch_matches_the_numpy_reference():
    rng = frame_rng(4, 0)
    lam = rng.uniform(0, 9.99, 5000).astype(np.float32)
    u = rng.random(5000)
    a, b = np.empty(5000), np.empty(5000, np.float32)
    sensor_module._invert_poisson_numpy(lam, u, a)
    sensor_module._inversion_kernel(lam, u, b, sensor_module._INV_K, sensor_module._PTRS_LAMBDA)
    np.testing.assert_array_equal(a, b)  # exact: same run
    sensor_module._inversion_kernel(np.float32([9.0, 10.0, 5e4]), u[:3], b[:3],
                                    sensor_module._INV_K, sensor_module._PTRS_LAMBDA)
    assert b[0] >= 0 and b[1] == -1 and b[2] == -1          # λ ≥ 10 is left to PTRS


def test_read_noise_quantile_is_finite_at_the_ends_of_the_uniforms():
    """A uniform that rounds to 0 or 1 in single precision (once in 2**24 pixels) would give
    erfinv(∓1) = ∓inf, then an out-of-range pixel.  The quantile must stay finite there."""
    llvm = sensor_module._backend("drjit")
    u = llvm.Float64([0.0, 2.0 ** -60, 0.5, 1.0 - 2.0 ** -24, 1.0 - 2.0 ** -53])
    z = np.asarray(sensor_module._dr_standard_normal(llvm, u))
    assert np.all(np.isfinite(z))
    assert z[0] == pytest.approx(stats.norm.ppf(2.0 ** -25), rel=1e-4) and z[2] == 0.0
    assert z[4] == pytest.approx(stats.norm.ppf(1.0 - 2.0 ** -24), rel=1e-4)


def test_dr_jit_inversion_matches_the_numpy_reference():
    """The unrolled terms and the loop that finishes the rare large counts (λ < 10)."""
    llvm = sensor_module._backend("drjit")
    rng = frame_rng(5, 0)
    lam = rng.uniform(0, 9.99, 20000)
    lam[:50] = 9.99                                # counts well past the unrolled terms
    u = rng.random(20000)
    u[:50] = 1.0 - rng.random(50) * 1e-6
    ref = np.empty(20000)
    sensor_module._invert_poisson_numpy(lam.astype(np.float32), u, ref)
    got = np.asarray(sensor_module._dr_invert_poisson(llvm, llvm.Float64(lam.astype(np.float32)),
                                                      llvm.Float64(u)))
    assert ref[:50].min() > sensor_module._UNROLL + 10
    np.testing.assert_array_equal(got, ref)   # exact: integers


def test_backends_draw_the_same_shot_noise_and_nearly_the_same_frame(rig):
    """Dr.Jit and numba run the same per-pixel streams: the same counts on both branches
    (λ < 10 and PTRS); the frames differ only where the read noise's single- against
    double-precision quantile crosses a rounding boundary."""
    rng = np.random.default_rng(2)
    lam = rng.uniform(0.0, 12.0, (400, 500)).astype(np.float32)
    lam[::7] = rng.uniform(10.0, 20000.0, lam[::7].shape)
    a = poisson_counts(lam, frame_rng(9, 4), backend="drjit")
    b = poisson_counts(lam, frame_rng(9, 4), backend="numba")
    np.testing.assert_array_equal(a, b)   # exact: integers
    model = SensorModel.from_rig(rig.replace(sensor={"dsnu_e": 3.0}))
    fa = apply_sensor(lam, model, frame_rng(9, 4), backend="drjit").astype(int)
    fb = apply_sensor(lam, model, frame_rng(9, 4), backend="numba").astype(int)
    assert np.abs(fa - fb).max() <= 1
    assert np.mean(fa != fb) < 1e-4
