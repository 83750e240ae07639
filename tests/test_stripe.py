"""Stripe extraction against synthetic Gaussian stripes with known centres."""

import math

import numpy as np
import pytest
from scipy.special import ndtr
from synth_frames import Camera, stripe_profile, to_dn

from scheimpflug.errors import FrameError
from scheimpflug.stripe import METHODS, extract_stripes, extract_stripes_batch

COLS = 64
BG_E = 40.0


def _frame(rng, sigma, total_e, rows=3000, cam=Camera(), centre=30.0):
    uc = centre + rng.uniform(-0.5, 0.5, rows)
    return to_dn(BG_E + total_e * stripe_profile(uc, sigma, COLS), rng, cam), uc


def crb_px(sigma, total_e, cam=Camera(), centre=30.0):
    """Cramér–Rao bound of the centre [px], RMS over sub-pixel phases.

    Pixel model: mean μ_k = b + A·[Φ((k+½−u)/σ) − Φ((k−½−u)/σ)] electrons,
    variance μ_k + σ_read² + g²/12 (shifted-Poisson approximation of
    Poisson + Gaussian read noise + quantisation).  Fisher matrix over
    (u, A, σ, b), all unknown; CRB = sqrt((I⁻¹)_uu).
    """
    k = np.arange(COLS, dtype=float)
    out = []
    for u0 in centre + np.linspace(-0.5, 0.5, 21):
        p0 = np.array([u0, total_e, sigma, BG_E])

        def mu(p):
            return p[3] + p[1] * (ndtr((k + .5 - p[0]) / p[2]) - ndtr((k - .5 - p[0]) / p[2]))

        J = []
        for i in range(4):
            dp = np.zeros(4)
            dp[i] = 1e-5 * max(1.0, abs(p0[i]))
            J.append((mu(p0 + dp) - mu(p0 - dp)) / (2 * dp[i]))
        J = np.array(J)
        var = mu(p0) + cam.read_noise_e ** 2 + cam.gain_e_per_dn ** 2 / 12
        out.append(math.sqrt(np.linalg.inv((J / var) @ J.T)[0, 0]))
    return float(np.sqrt(np.mean(np.square(out))))


@pytest.mark.parametrize("sigma", [1.0, 1.5, 2.5])
@pytest.mark.parametrize("total_e", [3000.0, 10000.0, 30000.0])
def test_best_detector_reaches_cramer_rao(sigma, total_e):
    """Windowed centre of gravity (window ±3σ): RMS error ≤ 1.3 × CRB, bias ≤ 0.01 px."""
    rng = np.random.default_rng(int(sigma * 10 + total_e))
    frame, uc = _frame(rng, sigma, total_e)
    p = extract_stripes(frame, "cog", window_px=math.ceil(3 * sigma))
    assert len(p) == frame.shape[0]
    err = p.u - uc[p.rows]
    crb = crb_px(sigma, total_e)
    assert abs(err.mean()) <= 0.01
    assert np.sqrt(np.mean(err ** 2)) <= 1.3 * crb, (np.std(err), crb)


@pytest.mark.parametrize("method", ["cog", "gaussian3", "blais-rioux"])
@pytest.mark.parametrize("sigma", [1.0, 1.6, 2.5])
def test_noise_free_subpixel_bias(method, sigma):
    """Noise-free pixel-integrated Gaussians over 41 sub-pixel phases: |bias| per phase."""
    uc = 30.0 + np.linspace(-0.5, 0.5, 41)
    frame = 100.0 + 20000.0 * stripe_profile(uc, sigma, COLS)
    p = extract_stripes(frame, method, window_px=math.ceil(3 * sigma))
    err = p.u - uc[p.rows]
    limit = {"cog": 0.01, "gaussian3": 0.01, "blais-rioux": 0.05}[method]
    assert len(p) == uc.size
    assert np.max(np.abs(err)) <= limit


def test_edge_is_the_right_boundary():
    """Method 'edge' lies σ·sqrt(2 ln 2) right of the centre (half maximum)."""
    sigma = 2.5
    uc = 30.0 + np.linspace(-0.5, 0.5, 21)
    frame = 100.0 + 40000.0 * stripe_profile(uc, sigma, COLS)
    p = extract_stripes(frame, "edge")
    expect = uc + math.sqrt(sigma ** 2 + 1 / 12) * math.sqrt(2 * math.log(2))
    assert np.max(np.abs(p.u - expect[p.rows])) < 0.1


def test_paper_method_is_the_boundary_in_whole_pixels():
    """Method 'paper': the last pixel at or above half maximum — the whole pixel in which the
    half-maximum crossing σ·sqrt(2 ln 2) right of the centre lies (noise free, 41 phases)."""
    sigma = 2.5
    uc = 30.0 + np.linspace(-0.5, 0.5, 41)
    frame = 100.0 + 40000.0 * stripe_profile(uc, sigma, COLS)
    p = extract_stripes(frame, "paper")
    crossing = uc + math.sqrt(sigma ** 2 + 1 / 12) * math.sqrt(2 * math.log(2))
    assert len(p) == uc.size and np.array_equal(p.u, np.round(p.u))  # exact: integers
    # the closed form holds to 0.1 px (test above): the red pixel is floor(crossing) except within
    # 0.1 px of a pixel border, where either neighbour is right
    lo, hi = np.floor(crossing[p.rows] - 0.1), np.floor(crossing[p.rows] + 0.1)
    assert np.all((p.u >= lo) & (p.u <= hi))
    clear = lo == hi
    assert clear.sum() > 30 and np.array_equal(p.u[clear], lo[clear])  # exact: integers


def test_blank_rows_rejected_and_stripe_rows_kept():
    rng = np.random.default_rng(5)
    stripe, uc = _frame(rng, 1.5, 8000.0, rows=400)
    blank = to_dn(np.full((400, COLS), BG_E), rng, Camera())
    frame = np.vstack([stripe, blank])
    p = extract_stripes(frame)
    assert set(p.rows) == set(range(400))
    assert np.all(p.score > 6)


def test_hot_pixel_is_not_a_stripe():
    rng = np.random.default_rng(6)
    frame = to_dn(np.full((50, COLS), BG_E), rng, Camera())
    frame[10, 20] = 4000
    assert len(extract_stripes(frame)) == 0
    stripe, uc = _frame(rng, 1.5, 8000.0, rows=50)
    stripe[:, 5] = 400  # hot column (peak ≈ 280 DN) under 1.8 × the stripe's: the stripe wins
    p = extract_stripes(stripe)
    assert len(p) == 50 and np.max(np.abs(p.u - uc)) < 0.5


def test_saturated_peak_flagged_and_centred():
    uc = np.full(10, 30.3)
    frame = np.minimum(100.0 + 1e5 * stripe_profile(uc, 2.0, COLS), 4095.0).astype(np.uint16)
    p = extract_stripes(frame, saturation_dn=4095)
    assert np.all(p.saturated)
    assert np.all(np.abs(p.u - 30.3) <= 0.5)
    q = extract_stripes(frame)  # uint16 default level 65535: not flagged
    assert not np.any(q.saturated)


def test_multi_peak_rule_prefers_the_nearer_peak():
    """A weaker peak at a smaller column (nearer the laser) wins above the ratio; not below."""
    rows = 20
    main = 10000.0 * stripe_profile(np.full(rows, 45.2), 1.5, COLS)
    near = stripe_profile(np.full(rows, 15.7), 1.5, COLS)
    strong = extract_stripes(100.0 + main + 5000.0 * near)
    assert np.allclose(strong.u, 15.7, atol=0.05) and np.all(strong.n_peaks == 2)
    weak = extract_stripes(100.0 + main + 1000.0 * near)
    assert np.allclose(weak.u, 45.2, atol=0.05)
    only = extract_stripes(100.0 + main + 5000.0 * near, multi_peak="strongest")
    assert np.allclose(only.u, 45.2, atol=0.05)
    far = extract_stripes(100.0 + main + 8000.0 * stripe_profile(np.full(rows, 55.0), 1.5, COLS))
    assert len(far) == rows  # a peak beyond the strongest never replaces it


@pytest.mark.parametrize("dtype,scale", [(np.uint8, 0.05), (np.uint16, 1.0), (np.float32, 1.0),
                                         (np.float64, 1.0)])
def test_dtypes(dtype, scale):
    uc = np.full(8, 31.25)
    frame = (scale * (20.0 + 3000.0 * stripe_profile(uc, 1.5, COLS))).astype(dtype)
    p = extract_stripes(frame, "gaussian3")
    assert len(p) == 8 and np.all(np.abs(p.u - 31.25) < 0.1)


def test_batch_matches_single():
    rng = np.random.default_rng(3)
    frames = [_frame(rng, 1.5, 5000.0, rows=30)[0] for _ in range(3)]
    for f, p in zip(frames, extract_stripes_batch(frames, "cog")):
        q = extract_stripes(f, "cog")
        assert np.array_equal(p.u, q.u) and np.array_equal(p.rows, q.rows)  # exact: same run


def test_bad_input():
    with pytest.raises(FrameError):
        extract_stripes(np.zeros((3, 4, 3), np.uint8))
    with pytest.raises(FrameError):
        extract_stripes(np.zeros((3, 4), np.uint8))
    with pytest.raises(FrameError):
        extract_stripes(np.array([["a"] * 10]))
    with pytest.raises(ValueError):
        extract_stripes(np.zeros((3, 20)), method="parabola")
    with pytest.raises(ValueError):
        extract_stripes(np.zeros((3, 20)), multi_peak="all")
    assert set(METHODS) == {"cog", "gaussian3", "blais-rioux", "edge", "paper"}


def test_track_rule_follows_the_continuous_stripe_not_a_wide_secondary(rng):
    """A nearer, wide (defocused) secondary peak in part of the rows: 'nearest' takes it, 'track'
    keeps the continuous, narrow stripe; prior_u and expected_u steer the choice."""
    rows = 60
    uc = 50.0 + 0.05 * np.arange(rows)
    frame = 100.0 + 8000.0 * stripe_profile(uc, 1.2, COLS)
    ghost = np.zeros(rows)
    ghost[20:35] = 1.0
    frame += 30000.0 * ghost[:, None] * stripe_profile(np.full(rows, 20.0), 3.5, COLS)
    frame = rng.poisson(frame).astype(np.float64)
    near = extract_stripes(frame, "cog", window_px=5)
    assert np.all(np.abs(near.u[20:35] - 20.0) < 1.0)          # the old rule takes the ghost
    track = extract_stripes(frame, "cog", window_px=5, multi_peak="track")
    assert len(track) == rows and np.max(np.abs(track.u - uc)) < 0.3
    assert np.all(track.n_peaks[20:35] == 2)
    # a prior at the ghost pulls those rows there; a range excluding the ghost forbids it
    prior = np.where(ghost > 0, 20.0, np.nan)
    pulled = extract_stripes(frame, "cog", window_px=5, multi_peak="track", prior_u=prior)
    assert np.sum(np.abs(pulled.u - 20.0) < 1.0) >= 10
    ranged = extract_stripes(frame, "cog", window_px=5, multi_peak="track", prior_u=prior,
                             expected_u=(30.0, 80.0))
    assert np.max(np.abs(ranged.u - uc)) < 0.3
    # on a clean frame 'track' equals the default rule
    clean = rng.poisson(100.0 + 8000.0 * stripe_profile(uc, 1.2, COLS)).astype(np.float64)
    a, b = extract_stripes(clean, "cog", window_px=5), extract_stripes(clean, "cog", window_px=5,
                                                                      multi_peak="track")
    assert np.array_equal(a.rows, b.rows) and np.allclose(a.u, b.u)  # exact: integers


def test_peak_choices_counts_against_truth():
    from scheimpflug.stripe import peak_choices

    rows = 6
    truth = np.array([10.0, 10.0, 10.0, 10.0, np.nan, 10.0])
    secondary = np.full((rows, 4), np.nan)
    secondary[1, 0] = 30.0
    uc = np.array([10.2, 30.1, 50.0, 10.0, 55.0, 10.0])
    frame = 100.0 + 5000.0 * stripe_profile(uc, 1.2, COLS)
    frame[5] = 100.0                                  # nothing detected in row 5
    p = extract_stripes(frame, "cog", window_px=5)
    c = peak_choices(p, truth, secondary)
    assert (c.rows, c.correct, c.secondary, c.other, c.missed) == (5, 2, 1, 2, 1)
    assert c.secondary_rate == pytest.approx(0.2)
    with pytest.raises(ValueError):
        peak_choices(p, truth, secondary, tol_px=0.0)


# ---------------------------------------------------------------- "auto" window (issue 16)


@pytest.mark.parametrize("sigma", [0.5, 1.0, 4.0, 6.0])
def test_auto_window_holds_three_sigma(sigma):
    """'auto' measures the stripe's width and uses ±(⌈3σ⌉ + 1) (at least ±3): near the Cramér–Rao bound on
    narrow and wide stripes alike, where the fixed ±7 window loses on both (noise of its background
    pixels on narrow stripes, cut tails on wide ones)."""
    rng = np.random.default_rng(int(10 * sigma))
    frame, uc = _frame(rng, sigma, 10000.0, rows=2000, centre=32.0)
    auto = extract_stripes(frame, "cog", window_px="auto")
    assert len(auto) == frame.shape[0]
    err = auto.u - uc[auto.rows]
    assert abs(err.mean()) <= 0.01
    assert np.sqrt(np.mean(err ** 2)) <= 1.3 * crb_px(sigma, 10000.0, centre=32.0)
    fixed = extract_stripes(frame, "cog")
    fixed_rms = np.sqrt(np.mean((fixed.u - uc[fixed.rows]) ** 2))
    assert np.sqrt(np.mean(err ** 2)) <= fixed_rms * (1.0 if sigma in (1.0, 4.0) else 0.8)


def test_stripe_narrower_than_a_pixel_is_not_a_hot_pixel():
    """A stripe of σ = 0.2 px leaves its neighbours under 10 % of the peak: still a stripe, because the
    rows above and below are lit at the same column; an isolated pixel stays a hot pixel."""
    rng = np.random.default_rng(4)
    uc = np.full(200, 30.0)  # centred on a pixel: the worst case
    frame = to_dn(BG_E + 20000.0 * stripe_profile(uc, 0.2, COLS), rng, Camera())
    assert len(extract_stripes(frame, "cog", window_px="auto")) == 200
    frame[100] = frame[100, 0]   # row 100: background only, and one hot pixel
    frame[100, 10] = 4000
    p = extract_stripes(frame, "cog", window_px="auto")
    assert 100 not in p.rows.tolist() and len(p) == 199


def test_isolated_rows():
    from scheimpflug.reconstruct import isolated_rows

    rows = np.array([3, 4, 5, 9, 20, 21])
    u = np.array([10.0, 10.5, 11.0, 10.0, 40.0, 45.0])
    assert isolated_rows(rows, u).tolist() == [False, False, False, True, True, True]
    assert isolated_rows(np.array([], dtype=int), np.array([])).shape == (0,)


def test_centre_of_gravity_stays_in_its_window_beside_a_step():
    """Pixels below the background (a dark region beside the stripe) must not throw the centre out of
    its window: with the background at 60 DN, a 0 DN step left of a 100 DN plateau outweighs the peak
    and the signed weights put the centre at 23.9 px, outside 12 ± 7 (issue 34, found on board-masked
    laser frames)."""
    from scheimpflug.stripe import _subpixel

    x = np.zeros(40)
    x[10:] = 100.0
    x[12] = 210.0
    u = _subpixel(x, 12, 60.0, 1, 7, 0.5)
    assert 5 <= u <= 19
    y = np.zeros(40)                       # an ordinary stripe keeps the signed weights' answer
    y[18:23] = [10.0, 60.0, 100.0, 60.0, 10.0]
    assert _subpixel(y, 20, 0.0, 1, 7, 0.5) == pytest.approx(20.0)
