"""Saturated stripe rows centred on their two edges, with their own uncertainty (issue 34 item 16).

Against closed forms: a pixel-integrated Gaussian stripe of known centre, clipped at full scale,
with white or shot + read noise (tests/synth_frames.py).  Then the folder, the cloud, the PLY,
the quality filter and ``reconstruct`` on synthetic scans, and FabScan's real frames (skipped,
saying so, without ``../shared/realdata``).
"""

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from synth_frames import Camera, stripe_profile, to_dn

from scheimpflug.app.cli import main
from scheimpflug.calibration import Calibration
from scheimpflug.io.frames import open_frame_folder
from scheimpflug.io.ply import read_point_cloud, write_point_cloud
from scheimpflug.point_quality import DEFAULT_FILTER, centre_crb_px, filter_counts, quality_mask
from scheimpflug.reconstruct import PointCloud, dn_per_electron, extract_folder_stripes
from scheimpflug.stripe import extract_stripes

COLS = 64
SAT = 4095
REAL = Path(__file__).resolve().parents[2] / "shared" / "realdata"


def _clipped(rng, sigma, factor, noise_dn, rows=3000, bg=100.0):
    """Frames of a Gaussian stripe whose true peak is ``factor`` × the clip, white noise; and the centres."""
    uc = 30.0 + rng.uniform(-0.5, 0.5, rows)
    peak = stripe_profile([30.0], sigma, COLS).max()
    x = bg + factor * (SAT - bg) * stripe_profile(uc, sigma, COLS) / peak + rng.normal(0.0, noise_dn, (rows, COLS))
    return np.clip(np.rint(x), 0, SAT).astype(np.uint16), uc


def _saturated_errors(frame, uc, sigma, **kw):
    # flanks beyond 5σ: a stripe clipped at a fraction of its peak has tails that reach further than
    # the ±(3σ + 1) an unclipped one needs, and in the flanks they pass for noise (a cautious σ)
    p = extract_stripes(frame, "cog", window_px=math.ceil(5 * sigma), saturation_dn=SAT, **kw)
    s = p.saturated
    return p.u[s] - uc[p.rows[s]], p.u_sigma[s], p


@pytest.mark.parametrize("sigma", [1.5, 3.0])
@pytest.mark.parametrize("factor", [1.2, 5.0, 100.0])
def test_noise_free_clipped_gaussian_centred_by_its_edges(sigma, factor):
    """The edges' midpoint of a clipped pixel-integrated Gaussian lies within 0.005 px of its centre.

    The run of saturated pixels' middle (the rule before issue 34) errs by up to half a pixel."""
    uc = 30.0 + np.linspace(-0.5, 0.5, 41)
    peak = stripe_profile([30.0], sigma, COLS).max()
    frame = np.minimum(100.0 + factor * (SAT - 100.0) * stripe_profile(uc, sigma, COLS) / peak, SAT)
    p = extract_stripes(frame, "cog", window_px=math.ceil(3 * sigma) + 1, saturation_dn=SAT)
    assert len(p) == 41 and np.all(p.saturated)
    assert np.max(np.abs(p.u - uc[p.rows])) < 0.005
    old = extract_stripes(frame, "cog", window_px=math.ceil(3 * sigma) + 1, saturation_dn=SAT, saturated="plateau")
    assert np.max(np.abs(old.u - uc[old.rows])) > 0.2


@pytest.mark.parametrize(("sigma", "factor", "noise_dn"),
                         [(1.5, 1.2, 10.0), (1.5, 5.0, 10.0), (1.5, 20.0, 30.0), (2.0, 2.0, 2.0), (3.0, 5.0, 10.0),
                          (3.0, 20.0, 30.0), (1.0, 5.0, 30.0)])
def test_stated_sigma_is_honest_over_noise_draws(rng, sigma, factor, noise_dn):
    """White noise: unbiased (|mean| < σ/10), the error over the stated σ has an RMS in [0.85, 1.2]."""
    frame, uc = _clipped(rng, sigma, factor, noise_dn)
    err, sig, _ = _saturated_errors(frame, uc, sigma)
    assert err.size > 2900
    assert abs(err.mean()) < 0.1 * np.sqrt(np.mean(sig ** 2))
    z = err / sig
    assert 0.85 <= np.sqrt(np.mean(z ** 2)) <= 1.2, (np.sqrt(np.mean(err ** 2)), np.sqrt(np.mean(sig ** 2)))
    assert np.mean(np.abs(z) > 4) < 0.005


@pytest.mark.parametrize("factor", [1.5, 10.0])
def test_shot_noise_needs_the_cameras_gain(rng, factor):
    """Shot + read noise (synth_frames): with the gain (DN per electron) the σ is honest, without it 2 × short."""
    cam = Camera()
    uc = 30.0 + rng.uniform(-0.5, 0.5, 3000)
    total = factor * SAT * cam.gain_e_per_dn / stripe_profile([30.0], 1.5, COLS).max()
    frame = to_dn(200.0 + total * stripe_profile(uc, 1.5, COLS), rng, cam)
    err, sig, _ = _saturated_errors(frame, uc, 1.5, dn_per_electron=1.0 / cam.gain_e_per_dn)
    assert 0.85 <= np.sqrt(np.mean((err / sig) ** 2)) <= 1.2
    err, sig, _ = _saturated_errors(frame, uc, 1.5)
    assert np.sqrt(np.mean((err / sig) ** 2)) > 2.0


def test_profile_fields_rules_and_bad_options():
    uc = np.full(10, 30.3)
    frame = np.minimum(100.0 + 1e5 * stripe_profile(uc, 2.0, COLS), SAT).astype(np.uint16)
    frame[5] = np.minimum(100.0 + 2000.0 * stripe_profile(uc[:1], 2.0, COLS)[0], SAT).astype(np.uint16)
    p = extract_stripes(frame, saturation_dn=SAT)
    assert p.saturated.tolist() == [True] * 5 + [False] + [True] * 4
    assert np.all(np.isfinite(p.u_sigma[p.saturated])) and np.isnan(p.u_sigma[5])
    np.testing.assert_allclose(p.u[p.saturated], 30.3, atol=0.01)
    old = extract_stripes(frame, saturation_dn=SAT, saturated="plateau")
    assert np.all(old.u[old.saturated] == 30.0)        # exact: integers (the run 27 … 33's middle)
    np.testing.assert_allclose(old.u_sigma[old.saturated], 1 / math.sqrt(24))
    track = extract_stripes(frame, "cog", saturation_dn=SAT, multi_peak="track")
    np.testing.assert_allclose(track.u[track.saturated], p.u[p.saturated], atol=1e-12)
    np.testing.assert_allclose(track.u_sigma[track.saturated], p.u_sigma[p.saturated], rtol=1e-9)
    for bad in ({"saturated": "drop"}, {"saturated_level": 1.0}, {"dn_per_electron": -1.0},
                {"dn_per_electron": math.nan}):
        with pytest.raises(ValueError, match="saturated"):
            extract_stripes(frame, saturation_dn=SAT, **bad)


# ---------------------------------------------------------------- folder, cloud, PLY, filter

ROWS = 120
U_H, V_H, F2, D0, C = 800.0, 60.0, -1.0e5, -100.0, 100.0
AXIS, RADIUS = 80.7, 20.0             # the stripe at column 177.72: between pixel centres


def _scan(path: Path, rng, peak_dn, n_frames=8, adc_bits=12, gain=None):
    """Frames of a cylinder turning on the axis (its near side: one column), the stripe's peak ``peak_dn``."""
    u_c = U_H + F2 / (AXIS - RADIUS - D0)
    cols = np.arange(300)
    (path / "frames").mkdir(parents=True)
    entries = []
    for i in range(n_frames):
        img = 100.0 + peak_dn * np.exp(-0.5 * ((cols - u_c) / 1.5) ** 2)[None, :] + rng.normal(0, 3.0, (ROWS, 300))
        cv2.imwrite(str(path / f"frames/{i:05d}.png"), np.clip(np.rint(img), 0, 2 ** adc_bits - 1).astype(np.uint16))
        entries.append({"file": f"frames/{i:05d}.png", "angle_deg": 360.0 * i / n_frames})
    sensor = {"rows": ROWS, "columns": 300, "adc_bits": adc_bits, **({"gain_e_per_dn": gain} if gain else {})}
    (path / "manifest.json").write_text(json.dumps({"scenario": "rotary", "rig": {"sensor": sensor},
                                                    "frames": entries}))
    return path, u_c


def test_folder_keeps_saturated_rows_with_their_sigma_or_drops_them(tmp_path, rng):
    scan, u_c = _scan(tmp_path / "scan", rng, peak_dn=12000.0)
    ff = open_frame_folder(scan)
    assert dn_per_electron(ff) == pytest.approx((4095 - 16) / 32000.0)      # the sensor's defaults: full well
    st = extract_folder_stripes(ff, "cog")
    sat, u, sig = (np.concatenate(x) for x in (st.saturated, st.u, st.centre_sigma_px))
    assert st.stats["saturated_rows"] == sat.size == 8 * ROWS and sat.all()
    assert np.all(np.abs(u - u_c) < 0.05) and np.all(sig < 0.05)
    assert sum(map(len, extract_folder_stripes(ff, "cog", saturated="drop").rows)) == 0
    alias = extract_folder_stripes(ff, "cog", keep_saturated=True)
    np.testing.assert_allclose(np.concatenate(alias.u), u, atol=0)                # exact: same code path
    assert sum(map(len, extract_folder_stripes(ff, "cog", keep_saturated=False).rows)) == 0
    with pytest.raises(ValueError, match="saturated"):
        extract_folder_stripes(ff, "cog", saturated="keep")
    dim, _ = _scan(tmp_path / "dim", rng, peak_dn=1500.0, gain=2.0)
    dimf = open_frame_folder(dim)
    assert dn_per_electron(dimf) == 0.5
    st = extract_folder_stripes(dimf, "cog")
    widths, snr, sig = (np.concatenate(x) for x in (st.stripe_width_px, st.snr, st.centre_sigma_px))
    np.testing.assert_allclose(sig, centre_crb_px(widths, snr))                     # unsaturated: the CRB


def test_point_cloud_and_ply_carry_the_saturation_and_the_sigma(tmp_path):
    n = 5
    cloud = PointCloud(np.arange(15.0).reshape(n, 3), np.zeros(n), np.arange(n), np.full(n, 100.0),
                       saturated=np.array([True, False, True, False, False]),
                       centre_sigma_px=np.array([0.02, 0.01, np.nan, 0.3, 0.05]))
    back = read_point_cloud(write_point_cloud(tmp_path / "c.ply", cloud))
    assert back.saturated.tolist() == cloud.saturated.tolist()
    np.testing.assert_allclose(back.centre_sigma_px, cloud.centre_sigma_px, rtol=1e-6)
    assert back.select(back.saturated).centre_sigma_px.size == 2
    bare = read_point_cloud(write_point_cloud(tmp_path / "d.ply", PointCloud(np.zeros((2, 3)), np.zeros(2),
                                                                              np.zeros(2, int), np.zeros(2))))
    assert bare.saturated is None and np.all(np.isnan(bare.centre_sigma_px))


def test_quality_filter_judges_a_saturated_point_by_its_centre_not_its_clipped_snr():
    width = np.full(4, 1.5)
    bound = float(centre_crb_px(1.5, DEFAULT_FILTER.min_snr))                    # 0.1 px
    cloud = PointCloud(np.zeros((4, 3)), np.zeros(4), np.arange(4), np.full(4, 4000.0),
                       snr=np.array([200.0, 200.0, 8.0, 200.0]), stripe_width_px=width,
                       saturated=np.array([True, True, True, False]),
                       centre_sigma_px=np.array([0.5 * bound, 2.0 * bound, 0.5 * bound, 2.0 * bound]))
    assert quality_mask(cloud, DEFAULT_FILTER).tolist() == [True, False, True, True]
    counts = filter_counts(cloud, DEFAULT_FILTER)
    assert counts["uncertain_saturated"] == 1 and counts["low_snr"] == 0 and counts["n_kept"] == 3


def _cal_file(tmp_path):
    cal = Calibration(hinge_u_px=U_H, hinge_v_px=V_H, F2_px_mm=F2, F2_sigma_px_mm=0.0, d0_mm=D0, C_mm=C,
                      C_sigma_mm=0.0, endpoint_fit_r2=(1.0, 1.0), method="paper", columns=300, rows=ROWS)
    cal.save(tmp_path / "cal.json")
    return tmp_path / "cal.json"


def test_reconstruct_centres_clipped_rows_on_the_cylinder(tmp_path, rng, capsys):
    """Every row clipped (peak 3 × full scale): the default keeps them on the cylinder, drop loses them all."""
    scan, _ = _scan(tmp_path / "scan", rng, peak_dn=12000.0)
    cal = _cal_file(tmp_path)
    base = ["reconstruct", str(scan), "--calibration", str(cal), "--axis-mm", str(AXIS), "--json", "--quiet",
            "--no-quality-filter"]
    radius_error = {}
    for rule in ("edges", "plateau"):
        out = tmp_path / f"{rule}.ply"
        assert main(base + ["--saturated", rule, "--out", str(out)]) == 0
        summary = json.loads(capsys.readouterr().out)
        assert summary["saturated"] == rule and summary["saturated_points"] == summary["n_points"] == 8 * ROWS
        cloud = read_point_cloud(out)
        assert cloud.saturated.all() and np.all(np.isfinite(cloud.centre_sigma_px))
        radius_error[rule] = np.abs(np.hypot(cloud.xyz_mm[:, 0], cloud.xyz_mm[:, 1]) - RADIUS)
    assert radius_error["edges"].max() < 0.005           # 0.05 px of 2.7 µm/px … at 60 mm: mm
    assert radius_error["plateau"].max() > 5 * radius_error["edges"].max()
    assert main(base + ["--keep-saturated", "--out", str(tmp_path / "k.ply")]) == 0
    assert json.loads(capsys.readouterr().out)["saturated"] == "edges"
    assert main(base + ["--saturated", "drop", "--out", str(tmp_path / "d.ply")]) == 2
    assert "saturated rows dropped" in capsys.readouterr().err
    assert main(base + ["--saturated", "drop", "--keep-saturated", "--out", str(tmp_path / "e.ply")]) == 2


# ---------------------------------------------------------------- FabScan's real frames

needs_real = pytest.mark.skipif(not REAL.is_dir(), reason=f"real frames absent ({REAL}): see its README")


def _along_scatter_px(st, saturated: bool) -> float:
    """Robust scatter of the centres along the stripe: second differences of three consecutive lines, /√6."""
    d2 = []
    for r, u, s in zip(st.rows, st.u, st.saturated):
        ok = (r[2:] - r[:-2] == 2) & (np.abs(np.diff(u)[1:]) < 2) & (np.abs(np.diff(u)[:-1]) < 2)
        c = ok & (s[1:-1] == saturated) & (s[2:] == saturated) & (s[:-2] == saturated)
        d2.append((u[2:] - 2 * u[1:-1] + u[:-2])[c])
    d2 = np.concatenate(d2)
    assert d2.size > 1000
    return float(1.4826 * np.median(np.abs(d2)) / math.sqrt(6))


@needs_real
def test_fabscans_saturated_rows_are_as_smooth_as_its_others(fabscan_scan, tmp_path, capsys):
    """scan-2_1: ≈ 27 % of the rows clip; centred on their edges they scatter along the bust as the
    unsaturated rows do (all 200 frames: 0.077 vs 0.078 px, benchmarks/bench_saturated_stripes.py),
    the plateau's middle (the old --keep-saturated) 4 × more; the back walls never clip."""
    ff = open_frame_folder(fabscan_scan)
    edges = extract_folder_stripes(ff, "cog")
    plateau = extract_folder_stripes(ff, "cog", saturated="plateau")
    unsat = _along_scatter_px(edges, False)
    assert _along_scatter_px(edges, True) < 1.25 * unsat
    assert _along_scatter_px(plateau, True) > 2.5 * unsat
    config = REAL / "fabscan" / "dummy.config.json"
    counts = {}
    for rule in ("edges", "drop"):
        for extra in ([], ["--no-quality-filter"]):
            assert main(["reconstruct", str(fabscan_scan), "--calibration", str(config), "--saturated", rule, "--json",
                         "--quiet", "--force", "--out", str(tmp_path / f"{rule}.ply"), *extra]) == 0
            counts[rule, bool(extra)] = json.loads(capsys.readouterr().out)
    saturated = counts["edges", True]["saturated_rows"]
    assert saturated > 0.2 * counts["edges", True]["n_points"]
    assert counts["edges", True]["n_points"] - counts["drop", True]["n_points"] == saturated    # every one kept
    assert counts["edges", False]["n_points"] > 1.15 * counts["drop", False]["n_points"]        # and most pass
    from scheimpflug.stripe import image_pixels

    u, _ = image_pixels(np.concatenate(edges.rows), np.concatenate(edges.u), edges.along)
    on_walls = (u <= 190) | ((u >= 1310) & (u <= 1460))
    assert np.concatenate(edges.saturated)[on_walls].mean() < 0.01
