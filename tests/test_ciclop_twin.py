"""The Ciclop camera's laser line on its pattern: the twin against the real frames (issue 36 item 6).

Synthetic checks of :mod:`scheimpflug.board_laser` (known planes and lines); on the real
frames of ``../shared/realdata/3dscanscience/`` (skipped, saying so, where absent): the
project's calibration of the 16 chessboard frames, the pattern's pose in ``pattern.png``, the
left laser's line on it, its plane through that line and the emitter placed by the second pose
(``laser-0-255-255-8.png``: the pattern turned, its laser-off frame bright enough at gain 8),
a rig from that calibration, the twin's laser frame at that pose, the stripe compared with
the real laser-minus-background frame (:func:`scheimpflug.compare.figures.measure_frame`).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from scheimpflug.board_laser import BoardLine, fit_line_3d, plane_of_lines, plane_through_line
from scheimpflug.errors import CalibrationError

REAL = Path(__file__).resolve().parents[2] / "shared" / "realdata"
DSS = REAL / "3dscanscience"
LP = DSS / "laser-on-pattern"
needs_real = pytest.mark.skipif(not LP.is_dir(), reason=f"the Ciclop/Horus frames are absent ({DSS})")
#: The column range of the left laser's line in both laser frames [px] (the right one lies beyond 480).
LEFT = (0.0, 480.0)


def _line(points) -> BoardLine:
    p = np.asarray(points, np.float64)
    return BoardLine(p, np.zeros((len(p), 2)), p[:, :2])


def test_a_plane_through_two_lines_and_through_a_line_and_its_emitter():
    n = np.array([-0.88, -0.02, 0.47])
    n /= np.linalg.norm(n)
    d = 150.0
    u = np.cross(n, [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    c = n * d
    t = np.linspace(-40, 40, 50)
    a = _line(c + 30 * u + np.outer(t, v))                  # two lines of the plane, 60 mm apart
    b = _line(c - 30 * u + np.outer(t, v + 0.3 * u))
    got_n, got_d, rms = plane_of_lines([a, b])
    assert np.allclose(got_n, n, atol=1e-9) and got_d == pytest.approx(d, abs=1e-9) and rms < 1e-9
    p0, w, line_rms = fit_line_3d(a)
    assert abs(abs(w @ v) - 1) < 1e-12 and line_rms < 1e-9
    emitter = c + 200 * u                                   # a point of the plane off the line
    got_n, got_d = plane_through_line(p0, w, emitter)
    assert np.allclose(got_n, n, atol=1e-9) and got_d == pytest.approx(d, abs=1e-9)
    with pytest.raises(CalibrationError, match="2 poses"):
        plane_of_lines([a])
    with pytest.raises(CalibrationError, match="emitter lies on"):
        plane_through_line(p0, w, p0 + 5 * w)


def test_render_target_pose_from_is_refused_without_its_camera_or_beside_drawn_poses(tmp_path, capsys):
    from scheimpflug.app.cli import main

    base = ["render", "target", "--preset", "paper", "--pattern", "chessboard:10x8:7", "--quiet",
            "--out", str(tmp_path / "out")]
    assert main([*base, "--pose-from", str(tmp_path / "a.png")]) != 0
    assert "--pose-from needs --pose-calibration" in capsys.readouterr().err
    assert main([*base, "--pose-from", "a.png", "--pose-calibration", "c.json", "--poses", "3"]) != 0
    assert "not with --poses" in capsys.readouterr().err
    assert main([*base, "--pose-calibration", "c.json"]) != 0
    assert "go with --pose-from" in capsys.readouterr().err
    cal = tmp_path / "cal.json"
    cal.write_text('{"camera_matrix": [[1000, 0, 320], [0, 1000, 240], [0, 0, 1]]}')
    assert main([*base, "--pose-from", "a.png", "--pose-calibration", str(cal)]) != 0
    assert "camera_matrix and dist_coeffs" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()                   # nothing written


def _red(path) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(path))[..., 0].astype(np.float64)


def _calibrate(tmp_path, capsys) -> dict:
    from scheimpflug.app.cli import main

    csv = tmp_path / "poses.csv"
    csv.write_text("file,pose,light\n" + "\n".join(f"frame{k}.jpg,{k},flood" for k in range(16)) + "\n")
    folder = tmp_path / "dss"
    cams = [str(DSS / "camera-calibration" / f"frame{k}.jpg") for k in range(16)]
    assert main(["import", *cams, "--scenario", "target", "--positions", str(csv), "--channel", "r",
                 "--out", str(folder), "--quiet"]) == 0
    assert main(["calibrate", str(folder), "--method", "target", "--pattern", "chessboard:11x6:13",
                 "--distortion", "opencv5", "--refine", "subpix", "--out", str(tmp_path / "cal.json"),
                 "--quiet"]) == 0
    capsys.readouterr()
    return json.loads((tmp_path / "cal.json").read_text())


def _laser_plane(cal: dict, spec):
    """The left laser's plane: through its line on pattern.png's pose, the emitter from both poses."""
    from scheimpflug.board_laser import board_line_points, board_pose

    k, dist = np.array(cal["camera_matrix"]), np.array(cal["dist_coeffs"][:5])
    m_x, _, _ = board_pose(_red(LP / "pattern.png"), k, dist, spec)
    m_n, gain, _ = board_pose(_red(LP / "laser-background-0-255-255-8.png"), k, dist, spec)
    assert gain > 1                                          # the laser-off frame is dim
    line_x = board_line_points(_red(LP / "laser-0-255-255-8-x.png") - _red(LP / "laser-background-0-255-255-8-x.png"),
                               k, dist, m_x, spec, LEFT)
    line_n = board_line_points(_red(LP / "laser-0-255-255-8.png") - _red(LP / "laser-background-0-255-255-8.png"),
                               k, dist, m_n, spec, LEFT)
    n2, d2, _ = plane_of_lines([line_x, line_n])
    emitter = np.array([d2 / n2[0], 0.0, 0.0])               # the camera's depth and height, on that plane
    c, w, _ = fit_line_3d(line_x)
    n, d = plane_through_line(c, w, emitter)
    # the second pose's line lies on the chosen plane (measured: 0.05 mm mean, 0.15 mm RMS)
    off = line_n.points_mm @ n - d
    assert abs(off.mean()) < 0.2 and np.sqrt(np.mean(off**2)) < 0.3
    return m_x, n, d


@pytest.fixture(scope="module")
def ciclop(tmp_path_factory):
    """Real and twin laser frames of pattern.png's pose, measured (module-scoped: one render)."""
    import warnings

    from scheimpflug.app.cli import main
    from scheimpflug.board_laser import board_pose
    from scheimpflug.calibration.pattern import parse_pattern
    from scheimpflug.compare.figures import measure_frame, region_lines
    from scheimpflug.model.rigfile import load_rig
    from sim.pose_twin import fit_waist_and_power, render_poses

    tmp = tmp_path_factory.mktemp("ciclop")

    class _Cap:                      # capsys is function-scoped: the CLI's stdout is not read here
        def readouterr(self):
            return None

    cal = _calibrate(tmp, _Cap())
    spec = parse_pattern("chessboard:11x6:13")
    m_x, n, d = _laser_plane(cal, spec)
    opencv = tmp / "ciclop-opencv.json"
    opencv.write_text(json.dumps({"camera_matrix": cal["camera_matrix"], "dist_coeffs": cal["dist_coeffs"][:5],
                                  "image_size": cal["image_size"], "laser_plane": [*(-n).tolist(), float(d)]}))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(["rig", "from-calibration", str(opencv), "--chain", "logitech_c270",
                     "--out", str(tmp / "rig.toml")]) == 0
    rig = load_rig(tmp / "rig.toml")
    render_poses(rig, [m_x], tmp / "twin", "chessboard:11x6:13", lights=("laser",), warn=lambda m: None)
    real = np.clip(_red(LP / "laser-0-255-255-8-x.png") - _red(LP / "laser-background-0-255-255-8-x.png"), 0, None)
    twin = _red(tmp / "twin" / "frames" / "00000.png")
    lines = region_lines({"part": (500.0, 981.0)}, real.shape[0])     # the line on the printed squares

    def measure(frame):
        left = np.zeros_like(frame)
        left[:, :480] = frame[:, :480]
        return measure_frame(left, lines, saturation_dn=255.0)["part"]

    (pos_r, fig_r, _), (pos_t, fig_t, _) = measure(real), measure(twin)
    # the waist and power identified from pattern.png's stripe (FWHM, peak), checked on the other pose
    fit = fit_waist_and_power(rig, m_x, "chessboard:11x6:13",
                              lambda f: tuple(measure(f.astype(np.float64))[1][k] for k in ("fwhm_px", "peak_dn")),
                              fig_r["fwhm_px"], fig_r["peak_dn"], tmp / "fit")
    k, dist = np.array(cal["camera_matrix"]), np.array(cal["dist_coeffs"][:5])
    m_n, _, _ = board_pose(_red(LP / "laser-background-0-255-255-8.png"), k, dist, spec)
    render_poses(rig.replace(laser={"waist_um": fit.waist_um, "power_mw": fit.power_mw}), [m_n], tmp / "held",
                 "chessboard:11x6:13", warn=lambda m: None)
    held_r = measure(np.clip(_red(LP / "laser-0-255-255-8.png") - _red(LP / "laser-background-0-255-255-8.png"),
                             0, None))[1]
    held_t = measure(_red(tmp / "held" / "frames" / "00000.png"))[1]
    return {"d": (pos_t - pos_r)[np.isfinite(pos_t - pos_r)], "real": fig_r, "twin": fig_t, "fit": fit,
            "held_real": held_r, "held_twin": held_t}


@needs_real
@pytest.mark.slow
@pytest.mark.render
def test_the_twin_puts_the_ciclop_stripe_where_the_real_one_is_on_most_lines(ciclop):
    """Guards what holds (measured: 441 lines, median -0.08 px, 0.534 px RMS on the 428 within 2 px)."""
    d = ciclop["d"]
    assert len(d) > 400
    assert abs(np.median(d)) < 0.25
    inner = d[np.abs(d) < 2.0]
    assert len(inner) > 0.9 * len(d) and np.sqrt(np.mean(inner**2)) < 0.6


@needs_real
@pytest.mark.slow
@pytest.mark.render
@pytest.mark.xfail(strict=True, reason="measured 4.75 px RMS over the 441 lines: 13 real lines where the cog detector "
                                       "takes other light 2-57 px off the line (rows at both ends and a few between), "
                                       "and the real stripe's own speckle jitter of 0.48 px RMS about a smooth "
                                       "curve, which a smooth twin stripe cannot share")
def test_ciclop_stripe_position_on_the_pattern_meets_the_issue_target(ciclop):
    d = ciclop["d"]
    assert np.sqrt(np.mean(d**2)) <= 0.5                     # issue 36's acceptance: ≤ 0.5 px RMS


@needs_real
@pytest.mark.slow
@pytest.mark.render
@pytest.mark.xfail(strict=True, reason="measured twin 3.07 px against real 4.16 px FWHM (-26 %): the twin's "
                                       "waist (150 µm) and power (5 mW) are the rig's unidentified defaults")
def test_the_unidentified_twin_gives_the_ciclop_stripe_width(ciclop):
    real, twin = ciclop["real"]["fwhm_px"], ciclop["twin"]["fwhm_px"]
    assert abs(twin - real) <= 0.15 * real                   # issue 36's acceptance: within 15 %


@needs_real
@pytest.mark.slow
@pytest.mark.render
def test_the_waist_and_power_are_identified_from_one_pose_and_the_level_holds_on_the_other(ciclop):
    """Measured: 289 µm, 9.76 mW in 13 renders; the other pose's peak 161 DN twin against 146 real (+10 %)."""
    fit = ciclop["fit"]
    assert fit.converged and 150 < fit.waist_um < 600 and fit.renders <= 20
    assert fit.fwhm_px == pytest.approx(ciclop["real"]["fwhm_px"], rel=0.02)
    real, twin = ciclop["held_real"]["peak_dn"], ciclop["held_twin"]["peak_dn"]
    assert abs(twin - real) <= 0.20 * real                   # issue 36's peak level target, held out


@needs_real
@pytest.mark.slow
@pytest.mark.render
@pytest.mark.xfail(strict=True, reason="measured on the held-out pose (the pattern turned 22°): twin 4.70 px against "
                                       "real 5.64 px FWHM (-16.6 %) with the waist and power identified on "
                                       "pattern.png's pose; the real stripe widens 36 % between the poses, the "
                                       "twin's 13 %")
def test_ciclop_stripe_width_on_the_held_out_pose_meets_the_issue_target(ciclop):
    real, twin = ciclop["held_real"]["fwhm_px"], ciclop["held_twin"]["fwhm_px"]
    assert abs(twin - real) <= 0.15 * real                   # issue 36's acceptance: within 15 %
