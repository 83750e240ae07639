"""`scheimpflug compare` and scheimpflug.compare: image figures of synthetic frames of known truth.

Each synthetic frame folder holds a stripe running along the rows (one stripe point per column, as
FabScan's camera sees it): a point-sampled Gaussian across it of known σ and peak, on a known
background with Gaussian noise, optionally with a wide Gaussian halo of known energy, clipped at a
known level, modulated along the stripe by a known contrast, shifted by a known amount.  The truths
below are closed forms of those parameters, not the measuring code's.
"""

from __future__ import annotations

import glob
import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.special import erf

from scheimpflug.app.cli import main

ACROSS, ALONG = 160, 240                  # frame rows (across the stripe) and columns (along it) [px]
REGIONS = {"wall_left": (0.0, 79.0), "part": (80.0, 239.0)}
REGIONS_ARG = "wall_left=0:79,part=80:239"
FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))     # 2.3548
REAL = Path(__file__).resolve().parents[2] / "shared" / "realdata"
CONFIG = REAL / "fabscan" / "dummy.config.json"
needs_real = pytest.mark.skipif(not (REAL / "fabscan" / "scan-2_1").is_dir(),
                                reason=f"real frames absent ({REAL}/fabscan/scan-2_1): see its README")


def _frame(angle_deg, rng, *, sigma=2.5, peak=2000.0, bg=100.0, noise=2.0, halo=0.0, halo_sigma=8.0,
           clip=4095, speckle=0.0, shift=0.0, ramp=None, wall_offset=0.0, across=ACROSS):
    """One 12-bit frame (uint16): the stripe at row 60 + 0.05 col + angle/10 + shift (+ wall_offset on the wall)."""
    col = np.arange(ALONG, dtype=np.float64)
    v0 = 60.0 + 0.05 * col + angle_deg / 10.0 + shift + np.where(col <= 79, wall_offset, 0.0)
    d = np.arange(across, dtype=np.float64)[:, None] - v0[None, :]
    amp = peak * (1.0 + speckle * rng.standard_normal(ALONG)) if ramp is None else ramp
    shape = np.exp(-0.5 * (d / sigma) ** 2) + halo * (sigma / halo_sigma) * np.exp(-0.5 * (d / halo_sigma) ** 2)
    img = bg + amp[None, :] * shape + noise * rng.standard_normal(d.shape)
    return np.clip(np.rint(img), 0, clip).astype(np.uint16)


def _folder(path, angles, seed=0, **kw) -> Path:
    """A frame folder (manifest + PNGs), stripe along the rows, 12-bit, one frame per angle in the order given."""
    path = Path(path)
    (path / "frames").mkdir(parents=True)
    rng = np.random.default_rng(seed)
    entries = []
    for i, a in enumerate(angles):
        name = f"frames/{i:05d}.png"
        assert cv2.imwrite(str(path / name), _frame(a, rng, **kw))
        entries.append({"file": name, "angle_deg": float(a)})
    (path / "manifest.json").write_text(json.dumps({
        "format": "scheimpflug-frames/1", "complete": True, "scenario": "rotary", "scenario_params": {},
        "adc_bits": 12, "stripe_along": "rows", "frames": entries}))
    return path


def _figures(path, regions=REGIONS, **kw):
    from scheimpflug.compare.figures import folder_figures

    return folder_figures(path, regions, **kw)


# ------------------------------------------------------------------ image figures against known truth


def test_width_peak_background_noise_detection_of_a_clean_stripe(tmp_path):
    sigma, peak, bg, noise = 2.5, 2000.0, 100.0, 2.0
    f = _figures(_folder(tmp_path / "f", [0, 10, 20, 30], sigma=sigma, peak=peak, bg=bg, noise=noise))
    for region in REGIONS:
        got = f[region]
        assert got["fwhm_px"] == pytest.approx(FWHM_PER_SIGMA * sigma, rel=0.03)
        # the highest sample lies within 0.5 px of the centre: bg + peak·exp(-0.5 (δ/σ)²), δ ≤ 0.5
        assert bg + peak * math.exp(-0.5 * (0.5 / sigma) ** 2) - 3 <= got["peak_dn"] <= bg + peak + 3
        assert got["background_dn"] == pytest.approx(bg, abs=0.5)
        assert got["noise_dn"] == pytest.approx(math.sqrt(noise ** 2 + 1 / 12), rel=0.04)  # + rounding
        assert got["saturated_fraction"] == 0.0
        assert got["detection_rate"] == 1.0
        assert abs(got["halo_fraction"]) < 0.005


def test_halo_fraction_of_a_wide_gaussian_wing(tmp_path):
    """Halo energy h of the core's in a Gaussian of σ_h: beyond ±3 FWHM out to +32 px, over the light within."""
    sigma, hs, h = 1.5, 8.0, 0.3
    f = _figures(_folder(tmp_path / "f", [0, 10, 20, 30], sigma=sigma, halo=h, halo_sigma=hs, noise=1.0))
    for region in REGIONS:
        w = f[region]["fwhm_px"]
        core, out = 3 * w, 3 * w + 32

        def inside(x, s):                       # fraction of a unit Gaussian's energy within |d| ≤ x
            return erf(x / (s * math.sqrt(2)))
        truth = h * (inside(out, hs) - inside(core, hs)) / (inside(core, sigma) + h * inside(core, hs))
        assert 0.03 < truth < 0.06
        assert f[region]["halo_fraction"] == pytest.approx(truth, rel=0.15)


def test_moat_of_a_sharpened_stripe_and_none_beside_a_clean_one(tmp_path):
    """A negative wide Gaussian under the stripe (what an unsharp mask gives): its closed-form lowest level."""
    sigma, hs, h, peak = 2.5, 6.0, -0.8, 2000.0
    f = _figures(_folder(tmp_path / "f", [0, 10, 20, 30], sigma=sigma, halo=h, halo_sigma=hs, noise=1.0, peak=peak,
                         bg=500.0))                     # above the moat: no clipping at 0
    clean = _figures(_folder(tmp_path / "c", [0, 10, 20, 30], sigma=sigma, noise=1.0, peak=peak))
    for region in REGIONS:
        w = f[region]["fwhm_px"]
        d = np.linspace(w, 3 * w, 2001)
        profile = peak * (np.exp(-0.5 * (d / sigma) ** 2) + h * (sigma / hs) * np.exp(-0.5 * (d / hs) ** 2))
        assert profile.min() < -250                      # a moat of 15 % of the peak
        # the lines' centre pixels sit up to ½ px off the centre: the mean profile is the closed form
        # smoothed over ±½ px, which lifts its lowest point by well under 2 %
        assert f[region]["moat_dn"] == pytest.approx(profile.min(), rel=0.03)
        # no moat: the Gaussian's lowest level in the band is at 3 FWHM (7 σ: 0 DN), within the mean
        # profile's noise (1 DN over ≥ 80 lines)
        assert abs(clean[region]["moat_dn"]) < 0.5


def test_saturated_fraction_and_a_clipped_stripe(tmp_path):
    """Stripe centred on whole pixels, peak rising along it: saturated where bg + A ≥ 4095."""
    bg = 100.0
    ramp = 4095.0 * np.linspace(0.5, 2.0, ALONG)      # A per column
    sat = (bg + ramp) >= 4095
    path = tmp_path / "f"
    (path / "frames").mkdir(parents=True)
    rng = np.random.default_rng(3)
    # angle 0 and integer rows: v0 = 60 + 0.05 col is whole every 20 columns; use a flat stripe instead
    frames = []
    for _ in range(3):
        d = np.arange(ACROSS, dtype=np.float64)[:, None] - 70.0
        img = bg + ramp[None, :] * np.exp(-0.5 * (d / 2.0) ** 2) + rng.standard_normal((ACROSS, ALONG))
        frames.append(np.clip(np.rint(img), 0, 4095).astype(np.uint16))
    entries = []
    for i, fr in enumerate(frames):
        cv2.imwrite(str(path / f"frames/{i:05d}.png"), fr)
        entries.append({"file": f"frames/{i:05d}.png", "angle_deg": float(i)})
    (path / "manifest.json").write_text(json.dumps({"format": "scheimpflug-frames/1", "complete": True,
                                                    "scenario": "rotary", "adc_bits": 12, "stripe_along": "rows",
                                                    "frames": entries}))
    f = _figures(path)
    for region, (lo, hi) in REGIONS.items():
        truth = float(sat[int(lo):int(hi) + 1].mean())
        assert f[region]["saturated_fraction"] == pytest.approx(truth, abs=1.5 / (hi - lo + 1))
    assert f["part"]["saturated_fraction"] > 0.5 and f["wall_left"]["saturated_fraction"] < 0.3
    assert f["part"]["peak_dn"] == 4095.0


def test_speckle_contrast_of_a_known_modulation(tmp_path):
    c = 0.25
    f = _figures(_folder(tmp_path / "f", [0, 10, 20, 30, 40], speckle=c, peak=1500.0))
    for region in REGIONS:
        assert f[region]["speckle_contrast"] == pytest.approx(c, rel=0.15)
    clean = _figures(_folder(tmp_path / "g", [0, 10], speckle=0.0, peak=1500.0))
    assert clean["part"]["speckle_contrast"] < 0.02


def test_positions_paired_by_angle_in_shuffled_order(tmp_path):
    from scheimpflug.compare.figures import stripe_positions
    from scheimpflug.compare.pairing import pair_by_angle
    from scheimpflug.compare.summary import compare_folders
    from scheimpflug.io.frames import open_frame_folder

    angles = [0, 10, 20, 30, 40]
    real = _folder(tmp_path / "real", angles, seed=1)
    twin = open_frame_folder(_folder(tmp_path / "twin", [30, 0, 40, 10, 20], seed=2, shift=0.4))
    pos = stripe_positions(real, REGIONS, frames=[2])
    truth = 60.0 + 0.05 * np.arange(80, 240) + 2.0
    assert pos["part"].shape == (1, 160)
    assert np.max(np.abs(pos["part"][0] - truth)) < 0.05
    rf = open_frame_folder(real)
    pairs = pair_by_angle(rf, twin, range(5))
    assert pairs.twin.tolist() == [1, 3, 4, 0, 2] and not pairs.unmatched_real
    res = compare_folders(rf, twin, REGIONS, pairs).result
    for region in REGIONS:
        p = res["regions"][region]["position_px"]
        assert p["mean"] == pytest.approx(0.4, abs=0.03)
        assert p["rms"] == pytest.approx(0.4, abs=0.05)
        assert p["n"] == 5 * (80 if region == "wall_left" else 160)
    assert res["frames"] == 5


# ------------------------------------------------------------------ detectors: straightness and stillness


class _ScaledPixels:
    """A stand-in calibration: the sheet is the image scaled by 0.1 mm/px (s = 0.1 v, h = 0.1 u)."""

    def stage_from_pixel(self, u, v):
        return 0.1 * np.asarray(v, float), 0.1 * np.asarray(u, float)


def test_wall_stillness_of_known_frame_offsets(tmp_path):
    """The wall's stripe moves by δ_k between frames: stillness = 0.1 mm · RMS(δ_k − mean δ) · cos(slope)."""
    from scheimpflug.compare.detectors import detector_figures, wall_points
    from scheimpflug.compare.figures import region_lines
    from scheimpflug.io.frames import open_frame_folder
    from scheimpflug.stripe import METHODS

    offsets = np.array([-0.6, 0.0, 0.6, 0.2])
    folders = []
    for name, offs in (("real", offsets), ("twin", np.zeros(4))):
        path = tmp_path / name
        (path / "frames").mkdir(parents=True)
        rng = np.random.default_rng(5)
        entries = []
        for i, o in enumerate(offs):
            cv2.imwrite(str(path / f"frames/{i:05d}.png"), _frame(0.0, rng, wall_offset=o, noise=1.0))
            entries.append({"file": f"frames/{i:05d}.png", "angle_deg": float(i)})
        (path / "manifest.json").write_text(json.dumps({"format": "scheimpflug-frames/1", "complete": True,
                                                        "adc_bits": 12, "stripe_along": "rows", "frames": entries}))
        folders.append(open_frame_folder(path))
    walls = {"wall_left": region_lines({"wall_left": REGIONS["wall_left"]}, ALONG)["wall_left"]}
    pts = [wall_points(f, range(4), walls, METHODS) for f in folders]
    out = detector_figures(pts[0], pts[1], _ScaledPixels(), 4, draws=50)
    truth = 0.1 * float(np.sqrt(np.mean((offsets - offsets.mean()) ** 2))) * math.cos(math.atan(0.05))
    assert set(out) == set(METHODS)
    for det, v in out.items():
        assert v["stillness_mm"]["real"] == pytest.approx(truth, abs=0.004), det
        assert v["stillness_mm"]["twin"] < 0.004, det               # a still twin wall
        # straightness adds each point's own error: "paper" gives whole pixels (uniform, 1/√12 px)
        own = 0.1 / math.sqrt(12) if det == "paper" else 0.0
        assert v["straightness_mm"]["real"] == pytest.approx(math.hypot(truth, own), abs=0.006), det
        lo, hi = v["straightness_mm"]["twin_lo90"], v["straightness_mm"]["twin_hi90"]
        assert lo <= v["straightness_mm"]["twin"] <= hi < own + 0.006, det      # the still twin: its own error


def test_a_wall_of_single_point_frames_gives_figures_not_a_crash():
    """A bootstrap draw of one frame's single wall point, repeated, has no line: that draw leaves the wall out
    (it crashed compare on a sharpened FabScan twin: numpy's SVD did not converge)."""
    from scheimpflug.compare.detectors import _bootstrap, _figures
    from scheimpflug.fixed_lines import fixed_line

    with pytest.raises(ValueError, match="3 distinct finite points, got 1"):
        fixed_line([24.7] * 3, [-93.0] * 3, [0, 1, 2])
    s, h, f = np.array([0.0, 10.0, 20.0]), np.array([0.0, 0.1, 0.0]), np.array([0, 1, 2])   # a point a frame
    assert _figures({"wall_left": (s[[0, 0, 0]], h[[0, 0, 0]], np.array([0, 1, 2]))}) == (
        pytest.approx(math.nan, nan_ok=True), pytest.approx(math.nan, nan_ok=True))
    st, sl = _bootstrap({"wall_left": (s, h, f)}, 3, 200, 7)
    rng = np.random.default_rng(7)                       # the bootstrap's own draws, in its order
    short = np.array([len(set(rng.integers(0, 3, 3))) < 3 for _ in range(200)])
    assert short.any() and not short.all()
    assert np.array_equal(np.isnan(st), short)           # exact: integers (booleans: a draw of < 3 frames is NaN)
    assert np.nanmax(st) == pytest.approx(0.1 * math.sqrt(2) / 3, rel=1e-6)   # 3 distinct points: a bent line


def _reference_wall_points(folder, frames, walls, detectors):
    """The walls' points as compare found them before one reading served both passes: each frame read
    again for each detector, every detector's stripe extracted on its own."""
    from scheimpflug.reconstruct import dn_per_electron
    from scheimpflug.stripe import extract_stripes, image_pixels, oriented

    out = {d: {w: ([], [], []) for w in walls} for d in detectors}
    for d in detectors:
        for j, i in enumerate(frames):
            raw = folder.read(int(i))
            prof = extract_stripes(oriented(raw, folder.stripe_along), d, window_px="auto",
                                   saturation_dn=folder.saturation_dn(raw), saturated="edges",
                                   dn_per_electron=dn_per_electron(folder))
            for w, lines in walls.items():
                m = (prof.rows >= lines[0]) & (prof.rows <= lines[-1])
                u, v = image_pixels(prof.rows[m], prof.u[m], folder.stripe_along)
                out[d][w][0].append(u)
                out[d][w][1].append(v)
                out[d][w][2].append(np.full(int(m.sum()), j, np.int64))
    return {d: {w: tuple(np.concatenate(a) for a in parts) for w, parts in per.items()} for d, per in out.items()}


def _reference_interval(sheet, n_frames, draws, seed):
    """The bootstrap as first written: each resample's points gathered frame by frame with a mask."""
    from scheimpflug.fixed_lines import fixed_line

    rng = np.random.default_rng(seed)
    st = []
    for _ in range(draws):
        draw = rng.integers(0, n_frames, n_frames)
        lines = []
        for s, h, f in sheet.values():
            parts = [(s[f == k], h[f == k], np.full(int((f == k).sum()), n)) for n, k in enumerate(draw)]
            lines.append(fixed_line(*(np.concatenate(p) for p in zip(*parts))))
        st.append(float(np.sqrt(np.mean([x.rms_mm ** 2 for x in lines]))))
    return float(np.percentile(st, 5)), float(np.percentile(st, 95))


def test_one_reading_gives_the_walls_points_and_figures_of_separate_passes(tmp_path):
    """compare reads each frame once for its figures and every detector's wall points (the figure
    detector's extraction shared) and resamples its bootstrap by index: the points and the detectors'
    block are exactly those of the separate passes and the masked resampling it replaced."""
    from scheimpflug.compare.detectors import _sheet_points, detector_figures
    from scheimpflug.compare.pairing import pair_by_angle
    from scheimpflug.compare.summary import compare_folders
    from scheimpflug.io.frames import open_frame_folder
    from scheimpflug.stripe import METHODS

    real = open_frame_folder(_folder(tmp_path / "real", [0, 10, 20], seed=3, wall_offset=0.3, speckle=0.2))
    twin = open_frame_folder(_folder(tmp_path / "twin", [20, 0, 10], seed=4, speckle=0.2, clip=2050))
    pairs = pair_by_angle(real, twin, range(3))
    comp = compare_folders(real, twin, REGIONS, pairs, wall_detectors=METHODS)
    walls = {"wall_left": comp.real.lines["wall_left"]}
    for got, folder, frames in ((comp.real, real, pairs.real), (comp.twin, twin, pairs.twin)):
        ref = _reference_wall_points(folder, frames, walls, METHODS)
        assert set(got.wall_points) == set(METHODS)
        for d in METHODS:
            for a, b in zip(got.wall_points[d]["wall_left"], ref[d]["wall_left"]):
                # exact: same run (one extraction of the same frame with the same options, twice)
                assert a.dtype == b.dtype and np.array_equal(a, b), d
            assert len(ref[d]["wall_left"][0]) > 60, d
    out = detector_figures(comp.real.wall_points, comp.twin.wall_points, _ScaledPixels(), 3, draws=20, seed=7)
    for d in METHODS:
        sheet = _sheet_points(comp.twin.wall_points[d], _ScaledPixels())
        lo, hi = _reference_interval(sheet, 3, 20, 7)
        # exact: copy (each resample gathers the same points in the same order; fixed_line's arithmetic after)
        assert (out[d]["straightness_mm"]["twin_lo90"], out[d]["straightness_mm"]["twin_hi90"]) == (lo, hi), d


# ------------------------------------------------------------------ the command


def test_compare_json_table_and_report(tmp_path, capsys):
    angles = [0, 10, 20, 30]
    real = _folder(tmp_path / "real", angles, seed=1)
    twin = _folder(tmp_path / "twin", angles + [50], seed=2, shift=-0.3)
    assert main(["compare", str(real), str(twin), "--regions", REGIONS_ARG, "--frames", "even", "--json",
                 "--quiet"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["frames"] == 2 and out["pairs"] == [[0, 0, 0.0], [2, 2, 20.0]]
    assert set(out["regions"]) == {"wall_left", "part"}
    for block in out["regions"].values():
        assert set(block) == {"position_px", "fwhm_px", "peak_dn", "saturated_fraction", "halo_fraction",
                              "background_dn", "noise_dn", "speckle_contrast", "detection_rate", "moat_dn"}
        assert block["position_px"]["mean"] == pytest.approx(-0.3, abs=0.03)
        assert block["fwhm_px"]["twin"] == pytest.approx(block["fwhm_px"]["real"], rel=0.03)
    assert out["detectors"] == {} and "no --calibration" in out["detectors_note"]
    # twin.json's regions are used, a twin folder holding frames/; the table names what it shows; pictures
    tdir = tmp_path / "twin_dir"
    tdir.mkdir()
    (tmp_path / "twin").rename(tdir / "frames")
    (tdir / "twin.json").write_text(json.dumps({"format": 1, "regions": {"part": [80, 239]}}))
    rep = tmp_path / "rep"
    assert main(["compare", str(real), str(tdir), "--quiet", "--frames", "1:2", "--report", str(rep)]) == 0
    text = capsys.readouterr()
    assert "1 frame pairs compared" in text.out and "twin.json" in text.out and "wall_left" not in text.out
    assert "position rms [px]" in text.out and "no twin frame" not in text.err
    assert sorted(p.name for p in rep.iterdir()) == ["frame_0001.png", "positions.png", "profiles.png"]
    for p in rep.iterdir():
        assert cv2.imread(str(p)) is not None


@pytest.mark.parametrize("case, needle", [
    ("angles", "no selected real frame has a twin frame at its angle"),
    ("region", "unknown region 'floor'"),
    ("frames_step", "the step must be ≥ 1"),
    ("frames_word", "expected all, even, odd"),
    ("frames_range", "frame 7 is not a frame"),
    ("size", "differ in size"),
])
def test_bad_input_one_clear_error(tmp_path, capsys, case, needle):
    real = _folder(tmp_path / "real", [0, 10, 20])
    twin_angles = [5, 15] if case == "angles" else [0, 10, 20]
    twin = _folder(tmp_path / "twin", twin_angles, across=ACROSS + 8 if case == "size" else ACROSS)
    args = {"region": ["--regions", "floor=0:10"], "frames_step": ["--frames", "0:3:0"],
            "frames_word": ["--frames", "some"], "frames_range": ["--frames", "0,7"]}.get(case, [])
    rep = tmp_path / "rep"
    status = main(["compare", str(real), str(twin), "--regions", REGIONS_ARG, *args, "--quiet",
                   "--report", str(rep)] if case != "region" else
                  ["compare", str(real), str(twin), *args, "--quiet", "--report", str(rep)])
    err = capsys.readouterr().err
    assert status == 2
    lines = [ln for ln in err.splitlines() if "error" in ln]
    assert len(lines) == 1 and needle in lines[0], err
    assert not rep.exists()


def test_unmatched_real_frames_are_warned_and_left_out(tmp_path, capsys):
    real = _folder(tmp_path / "real", [0, 10, 20, 30])
    twin = _folder(tmp_path / "twin", [0, 20, 30])
    assert main(["compare", str(real), str(twin), "--regions", REGIONS_ARG, "--json", "--quiet"]) == 0
    cap = capsys.readouterr()
    assert json.loads(cap.out)["frames"] == 3 and json.loads(cap.out)["unmatched_real"] == [1]
    assert "1 selected real frame(s) have no twin frame at their angle" in cap.err


# ------------------------------------------------------------------ real frames


@needs_real
@pytest.mark.slow
def test_real_fabscan_frames_against_themselves(tmp_path, capsys):
    """Three frames of scan-2_1 compared with themselves: position rms 0, every real/twin pair equal."""
    from scheimpflug.calibration.fabscan import fabscan_angles_deg

    files = sorted(glob.glob(str(REAL / "fabscan" / "scan-2_1" / "*.jpg")))[:3]
    angles = fabscan_angles_deg(200, 6400, resolution=2)[:3]
    scan = tmp_path / "scan"
    assert main(["import", *files, "--channel", "r", "--stripe-along", "rows", "--quiet",
                 f"--angles-deg={','.join(f'{a:g}' for a in angles)}", "--out", str(scan)]) == 0
    capsys.readouterr()
    assert main(["compare", str(scan), str(scan), "--regions", "wall_left=0:190,part=480:890,table=1310:1460",
                 "--calibration", str(CONFIG), "--json", "--quiet"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["frames"] == 3
    for name, block in out["regions"].items():
        # exact: same run (one folder's frames measured twice by the same code)
        assert block["position_px"]["rms"] == 0.0 and block["position_px"]["n"] > 100, name
        for key, pair in block.items():
            if key != "position_px":
                assert pair["real"] == pair["twin"], (name, key)      # exact: same run
        assert block["peak_dn"]["real"] <= 255                    # the JPEG's own 8-bit DN
    assert set(out["detectors"]) == {"blais-rioux", "cog", "edge", "gaussian3", "paper"}
    for det, v in out["detectors"].items():
        for fig in ("straightness_mm", "stillness_mm"):
            # exact: same run
            assert v[fig]["real"] == v[fig]["twin"] and math.isfinite(v[fig]["real"]), (det, fig)
            assert v[fig]["twin_lo90"] <= v[fig]["twin_hi90"], (det, fig)


def _imported_real(path, angles):
    """A real folder as ``import`` writes it: 8-bit grey frames of the red channel (no noise, peak 180 DN)."""
    real = _folder(path, angles, seed=1, peak=180.0, bg=5.0, noise=0.0, clip=255)
    m = json.loads((real / "manifest.json").read_text())
    m.update(adc_bits=8, channel="r", source="scheimpflug import")
    (real / "manifest.json").write_text(json.dumps(m))
    for f in sorted(glob.glob(str(real / "frames" / "*.png"))):
        assert cv2.imwrite(f, cv2.imread(f, cv2.IMREAD_UNCHANGED).astype(np.uint8))
    return real


def test_a_twin_written_as_its_camera_writes_is_imported_like_the_real_frames(tmp_path, capsys):
    """The twin's frames as RGB JPEG (the red channel the stripe, green and blue a tenth of it), the real
    ones an imported grey folder (``channel`` r): compare imports the twin's with the real folder's
    channel and stripe direction, and finds the known shift and peak (JPEG at quality 100, 4:4:4: within
    0.05 px and 3 DN; 4:2:0 would halve the red's resolution across the stripe and lower its peak)."""
    angles = [0, 10, 20]
    real = _imported_real(tmp_path / "real", angles)
    twin = tmp_path / "twin"
    (twin / "frames").mkdir(parents=True)
    rng, entries = np.random.default_rng(2), []
    for i, a in enumerate([20, 0, 10]):
        red = _frame(a, rng, peak=180.0, bg=5.0, noise=0.0, clip=255, shift=0.4).astype(np.uint8)
        bgr = np.dstack([red // 10, red // 10, red])
        name = f"frames/{i:05d}.jpg"
        assert cv2.imwrite(str(twin / name), bgr, [cv2.IMWRITE_JPEG_QUALITY, 100, cv2.IMWRITE_JPEG_SAMPLING_FACTOR,
                                                   cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444])   # no chroma blur
        entries.append({"file": name, "angle_deg": float(a)})
    (twin / "manifest.json").write_text(json.dumps({
        "format": "scheimpflug-frames/1", "complete": True, "scenario": "rotary", "scenario_params": {},
        "adc_bits": 8, "stripe_along": "rows", "frames": entries}))
    assert main(["compare", str(real), str(twin), "--regions", REGIONS_ARG, "--json", "--quiet"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["frames"] == 3
    for region in REGIONS:
        assert res["regions"][region]["position_px"]["mean"] == pytest.approx(0.4, abs=0.05)
        assert res["regions"][region]["peak_dn"]["twin"] == pytest.approx(res["regions"][region]["peak_dn"]["real"],
                                                                          abs=3.0)


def test_a_twin_whose_faint_stripe_the_direction_check_refuses_is_compared(tmp_path, capsys):
    """The twin's RGB frames: a faint stripe along the rows and a glaring line down the image (a lit
    edge) that the importer's direction check takes for the stripe.  compare imports them with the
    real folder's direction as known (issue 36: they were refused) and measures the stripe."""
    from scheimpflug.errors import FrameError
    from scheimpflug.io.importer import frames_with_angles, import_frames

    angles = [0, 10, 20]
    real = _imported_real(tmp_path / "real", angles)
    twin = tmp_path / "twin"
    (twin / "frames").mkdir(parents=True)
    rng, entries = np.random.default_rng(2), []
    col = np.arange(ALONG)
    for i, a in enumerate(angles):
        red = _frame(a, rng, peak=14.0, bg=20.0, noise=1.0, clip=255, shift=0.4).astype(np.float64)
        red += 230.0 * np.exp(-0.5 * ((col - 200.0) / 1.2) ** 2)[None, :]        # the glare line, every row
        bgr = np.dstack([np.full_like(red, 3), np.full_like(red, 3), np.clip(red, 0, 255)]).astype(np.uint8)
        name = f"frames/{i:05d}.png"
        assert cv2.imwrite(str(twin / name), bgr)
        entries.append({"file": name, "angle_deg": float(a)})
    (twin / "manifest.json").write_text(json.dumps({
        "format": "scheimpflug-frames/1", "complete": True, "scenario": "rotary", "scenario_params": {},
        "adc_bits": 12, "stripe_along": "rows", "frames": entries}))
    with pytest.raises(FrameError, match="--stripe-along rows, but the stripe runs down the image"):
        import_frames(frames_with_angles([twin / e["file"] for e in entries], angles), tmp_path / "checked",
                      channel="r", stripe_along="rows")
    capsys.readouterr()
    assert main(["compare", str(real), str(twin), "--regions", "part=80:180", "--json", "--quiet"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["frames"] == 3
    assert res["regions"]["part"]["position_px"]["mean"] == pytest.approx(0.4, abs=0.1)   # faint: 14 DN, σ 1 DN
