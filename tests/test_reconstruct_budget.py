"""Error budget on synthetic data with known errors."""

import types

import numpy as np
import pytest

from scheimpflug.budget import calibration_error, error_budget, extraction_error, sheet_shift_mm
from scheimpflug.model.hinge import stage_from_pixel as sheet_from_pixel

TRUE = types.SimpleNamespace(hinge_u_px=3196.0, hinge_v_px=771.0, F2_px_mm=-1.4292e6,
                             d0_mm=-466.0, C_mm=149.10)


def _with(**changes):
    return types.SimpleNamespace(**{**vars(TRUE), **changes})


def test_sheet_shift_matches_finite_difference(rng):
    u, v = rng.uniform(0, 1215, 100), rng.uniform(0, 1935, 100)
    args = [getattr(TRUE, k) for k in ("hinge_u_px", "hinge_v_px", "F2_px_mm", "d0_mm", "C_mm")]
    eps = 1e-4
    s1, h1 = sheet_from_pixel(u + eps, v, *args)
    s0, h0 = sheet_from_pixel(u - eps, v, *args)
    dd, dh = sheet_shift_mm(eps * 2, u, v, TRUE)
    np.testing.assert_allclose(dd, s1 - s0, rtol=1e-6)
    np.testing.assert_allclose(dh, h1 - h0, rtol=1e-5, atol=1e-12)


def test_extraction_bias_and_rms(rng):
    rows_n, frames = 1936, 6
    truth, mrows, mu = [], [], []
    for _ in range(frames):
        tu = np.full(rows_n, np.nan)
        lit = np.arange(300, 1300)
        tu[lit] = 600 + 50 * np.sin(lit / 100)
        det = lit[::2]                                     # every other row detected
        u = tu[det] + 0.05 + rng.normal(0, 0.1, det.size)  # bias 0.05 px, sigma 0.1 px
        det = np.r_[det, 1500]                             # one spurious detection (no truth)
        u = np.r_[u, 700.0]
        u[0] += 10                                         # one wrong detection (far off)
        truth.append(tu), mrows.append(det), mu.append(u)
    out = extraction_error(mrows, mu, truth, calibration=TRUE)
    assert out["n_truth_rows"] == frames * 1000
    assert out["n_detected"] == frames * 501
    assert out["n_spurious"] == frames and out["n_wrong"] == frames
    assert out["n_matched"] == frames * 499
    assert out["n_missed"] == frames * 500
    assert out["bias_px"] == pytest.approx(0.05, abs=0.006)        # 3 sigma of a 3000-sample mean
    assert out["std_px"] == pytest.approx(0.1, rel=0.05)
    # mm: |dD/du| = |F2|/(u - u_h)^2 ≈ 1.4292e6 / 2596^2 ≈ 0.212 mm/px near u = 600
    assert out["rms_distance_mm"] == pytest.approx(out["rms_px"] * 1.4292e6 / (3196 - 600) ** 2, rel=0.05)
    assert out["sheet_rms_mm"] >= out["rms_distance_mm"]


def test_extraction_rejects_bad_rows():
    with pytest.raises(ValueError):
        extraction_error([np.array([5000])], [np.array([1.0])], [np.full(100, 1.0)])
    with pytest.raises(ValueError):
        extraction_error([np.array([1])], [np.array([1.0])], [])


def test_perfect_calibration_has_zero_error():
    out = calibration_error(TRUE, TRUE, 1216, 1936)
    assert out["rms_mm"] == 0 and out["stage_error_mm"]["max_abs"] == 0


def test_d0_error_is_a_uniform_shift_cancelled_by_the_axis():
    cal = _with(d0_mm=-465.5)
    out = calibration_error(cal, TRUE, 1216, 1936)
    assert out["stage_error_mm"]["rms"] == pytest.approx(0.5, abs=1e-9)
    assert out["height_error_mm"]["max_abs"] == 0
    assert out["parameters"]["d0_mm"]["error"] == pytest.approx(0.5)
    # an axis located with the same calibration is off by the same 0.5 mm: radii are right
    out = calibration_error(cal, TRUE, 1216, 1936, axis_mm=179.95, axis_truth_mm=179.45)
    assert out["radial_error_mm"]["max_abs"] < 1e-9 and out["rms_mm"] < 1e-9


def test_f2_error_grows_with_distance():
    out = calibration_error(_with(F2_px_mm=TRUE.F2_px_mm * 1.001), TRUE, 1216, 1936)
    # δs = 0.001·F²/(u − u_h): 0.001 × 447.2 mm at column 0, 0.001 × 721.5 mm at the last column
    assert out["stage_error_mm"]["near_mean"] == pytest.approx(0.001 * 1.4292e6 / 3196, rel=1e-9)
    assert out["stage_error_mm"]["far_mean"] == pytest.approx(0.001 * 1.4292e6 / (3196 - 1215), rel=1e-9)
    assert out["parameters"]["F2_px_mm"]["relative_error"] == pytest.approx(0.001)


def test_budget_summary_quadrature():
    ext = {"sheet_rms_mm": 0.03}
    cal = {"rms_mm": 0.04}
    d = np.full(100, 0.05)
    out = error_budget(ext, cal, d, signed=False)
    assert out["summary"]["quadrature_mm"] == pytest.approx(0.05)
    assert out["summary"]["total_rms_mm"] == pytest.approx(0.05)
    assert out["summary"]["unexplained_rms_mm"] == pytest.approx(0.0, abs=1e-7)
    assert out["total"]["n_points"] == 100
