"""`scheimpflug calibrate DIR`: the paper's calibration, the general model, or the better of both."""

from __future__ import annotations

import math
import sys
import warnings

from scheimpflug.app.commands._common import (
    add_allow_incomplete_option,
    add_force_option,
    check_output,
    check_plot,
    finite_json,
    number,
    open_frames,
    print_json,
)


def add_parser(sub):
    p = sub.add_parser("calibrate", help="calibrate from plate frames (paper Section 3, or the general model)",
                       description="Calibrate from a frame folder of a plate moved along the "
                                   "sheet: image hinge, F², d0 and C (paper Eqs. 11–12) by the "
                                   "paper's endpoint method and a refined joint fit, and a general "
                                   "model (sheet homography + radial distortion) for rigs with "
                                   "sensor roll or lens distortion; with the standard errors of "
                                   "the paper form's constants.")
    p.add_argument("dir", metavar="DIR", help="frame folder (manifest.json + frames/)")
    p.add_argument("--plate-height-mm", type=number(0, 1e4, lo_open=True, unit="mm"), default=None,
                   help="plate height [mm] (default: manifest scenario_params or 89)")
    p.add_argument("--out", metavar="CAL.json", help="write the calibration here")
    p.add_argument("--json", action="store_true", help="print the result as one JSON object")
    p.add_argument("--plot", metavar="FILE.png", help="draw the paper's Fig. 3(b)/(c)")
    p.add_argument("--model", choices=("paper", "general", "auto"), default="auto",
                   help="paper form (Eqs. 11–12), general model (homography + radial distortion), or "
                        "auto (default): the general model when an F-test on the residuals finds it "
                        "significantly better and it removes ≥ 20 %% of the residual sum of squares")
    p.add_argument("--method", choices=("paper", "refined", "best", "general", "target"), default="best",
                   help="paper form's estimate (default best: smaller standard error of u_h); general = "
                        "--model general with the best estimate as its start; target = no stage: a printed "
                        "pattern in several poses and the laser line on it (--pattern)")
    p.add_argument("--detector", choices=("gaussian3", "cog", "blais-rioux", "edge", "paper"),
                   default="cog",
                   help="stripe detector (default cog: windowed centre of gravity, unbiased on "
                        "wide stripes; edge = the paper's light-bar edge, sub-pixel; paper = the "
                        "paper's own processing in whole pixels, use with --method paper)")
    p.add_argument("--opencv", metavar="FILE.json",
                   help="also write the calibration as OpenCV's tilted camera model + laser plane "
                        "(JSON; .yml/.yaml/.xml through cv2.FileStorage)")
    p.add_argument("--rig", metavar="RIG.toml",
                   help="rig file for the lens focal length and pixel pitch (default: the manifest's "
                        "rig, else the paper's, assumed); they set the camera intrinsics of the "
                        "general model and of the OpenCV export")
    t = p.add_argument_group("--method target (scheimpflug/calibration/target.py)")
    t.add_argument("--pattern", metavar="SPEC",
                   help="the printed pattern: chessboard:COLSxROWS:SQUARE_MM (inner corners), "
                        "charuco:COLSxROWS:SQUARE_MM:MARKER_MM[:DICT] (squares; partly visible boards "
                        "are used), circles:COLSxROWS:PITCH_MM[:DIAMETER_MM]")
    t.add_argument("--tilt", choices=("auto", "focus", "rig", "none", "free"), default="auto",
                   help="how the sensor tilt τx, τy is found: focus = the camera is focused on the laser "
                        "sheet (Scheimpflug; needs the pixel pitch), rig = held at the manifest rig's design, "
                        "none = τ = 0 (an ordinary camera), free = OpenCV fits it (told only by the "
                        "distortion); auto (default): focus for a tilted rig in the manifest with laser "
                        "frames, rig without them, else none")
    t.add_argument("--distortion", choices=("none", "k1", "k1k2", "opencv5"), default="k1k2",
                   help="distortion terms fitted (default k1k2; opencv5 = k1, k2, p1, p2, k3, OpenCV's "
                        "default)")
    t.add_argument("--pixel-pitch-um", type=number(0, 1e3, lo_open=True, unit="µm"), default=None,
                   help="the sensor's pixel pitch [µm] for --tilt focus (default: --rig or the manifest's rig)")
    t.add_argument("--refine", choices=("model", "subpix"), default="model",
                   help="corner refinement: model = a blurred corner's model fitted (unbiased by defocus, "
                        "default), subpix = cv2.cornerSubPix with a window of 0.2 × the square side")
    t.add_argument("--on-table", metavar="DIR",
                   help="frames of the pattern standing on the rotary table at several angles (render target "
                        "--on-table): the rotary axis, in the same calibration ('axis'; reconstruct uses it)")
    t.add_argument("--f-number", type=number(0, 1e3, lo_open=True, unit=""), default=None,
                   help="the lens's f-number at the calibration (default: the manifest's rig): with --tilt focus "
                        "it sizes the blur spots whose centroid shift on the tilted sensor is taken out")
    t.add_argument("--stripe-along", choices=("columns", "rows"), default=None,
                   help="which way the laser line runs in the image: columns (down the image, one point per "
                        "row) or rows (default: the frame folder's, as import --stripe-along recorded it; "
                        "else columns)")
    t.add_argument("--laser-background", choices=("auto", "pose", "none"), default="auto",
                   help="what is subtracted from a laser frame before its line is found: its pose's laser-off "
                        "frame (light 'background') always, unless none; else its pose's flood-lit frame — pose: "
                        "always, auto (default): when the two were taken under the same light (the print shows in "
                        "their difference at no more than 25 %% of its contrast) or the set in room light "
                        "(import --room-light)")
    g = p.add_argument_group("stated accuracy (a warning when 2 standard errors exceed it)")
    g.add_argument("--accuracy-hinge-px", type=float, default=0.5, help="u_h and v_h [px] (default 0.5)")
    g.add_argument("--accuracy-relative", type=float, default=5e-4,
                   help="F² and C, relative (default 5e-4 = 0.05 %%)")
    g.add_argument("--accuracy-d0-resolution", type=float, default=0.1,
                   help="d0, in units of the distance resolution at the centre column (default 0.1)")
    add_force_option(p)
    add_allow_incomplete_option(p)
    p.add_argument("--quiet", action="store_true", help="no progress display")
    p.set_defaults(func=_run)
    return p


def _pm(x: float, fmt: str) -> str:
    return "–" if not math.isfinite(x) else format(x, fmt)


def _summary(res) -> str:
    pr = res.paper
    lines = []
    for c in (pr.paper, pr.refined):
        mark = "*" if c is res.chosen else " "
        lines.append(f"{mark} {c.method:8s} hinge = ({c.hinge_u_px:9.2f} ± {_pm(c.hinge_u_sigma_px, '.3g')}, "
                     f"{c.hinge_v_px:8.2f} ± {_pm(c.hinge_v_sigma_px, '.3g')}) px  "
                     f"F² = {c.F2_px_mm:.6g} ± {_pm(c.F2_stderr_px_mm, '.3g')} px·mm  "
                     f"d0 = {c.d0_mm:.3f} ± {_pm(c.d0_sigma_mm, '.3g')} mm  "
                     f"C = {c.C_mm:.4f} ± {_pm(c.C_stderr_mm, '.3g')} mm")
    b = pr.best
    lines.append("  (± standard errors)  per-frame spread σ(F²) = "
                 f"{_pm(b.F2_sigma_px_mm, '.3g')} px·mm, σ(C) = {_pm(b.C_sigma_mm, '.3g')} mm")
    g = res.general
    cam = g.camera if g is not None else None
    mark = "*" if g is not None and res.chosen is g else " "
    lines.append("  general  unavailable" if g is None else
                 f"{mark} general  k1 = {cam.k1:.5g}, principal point ({cam.principal_px[0]:.1f}, "
                 f"{cam.principal_px[1]:.1f}) px, residual {g.residual_rms_px:.4f} px RMS, "
                 f"σ over the field {g.field_sigma_mm.get('stage_rms', float('nan')):.3g} mm (stage), "
                 f"{g.field_sigma_mm.get('height_rms', float('nan')):.3g} mm (height)")
    r2 = pr.paper.endpoint_fit_r2
    lines.append(f"  endpoint fits R² = {r2[0]:.6f} (top), {r2[1]:.6f} (bottom); "
                 f"{len(res.measurements)} frames with a stripe, {pr.best.n_frames_both_edges} with both edges, "
                 f"{len(res.skipped)} skipped")
    lines.append(f"  model: {res.selection.reason}")
    return "\n".join(lines)


def _optics(args, folder):
    """(f [mm], p [µm], assumed) from --rig, else the manifest's rig, else the paper's (each on its own)."""
    from scheimpflug.sheet_model import DEFAULT_FOCAL_LENGTH_MM, DEFAULT_PIXEL_PITCH_UM

    if args.rig:
        from scheimpflug.model.rig import load_rig

        rig = load_rig(args.rig)
        return rig.lens.focal_length_mm, rig.sensor.pixel_pitch_um, False
    f, p = folder.rig_value("lens", "focal_length_mm"), folder.rig_value("sensor", "pixel_pitch_um")
    return float(f or DEFAULT_FOCAL_LENGTH_MM), float(p or DEFAULT_PIXEL_PITCH_UM), f is None or p is None


def _result_dict(res) -> dict:
    d = res.chosen.to_json_dict()
    d["model"] = "general" if res.chosen is res.general else "paper"
    d["selection"] = res.selection.to_json_dict()
    if d["model"] == "paper" and res.general is not None:
        d["general"] = res.general.to_json_dict()["general"]
    return d


def _target_summary(res) -> str:
    c = res.calibration
    k, d = c.camera.camera_matrix, c.camera.dist_coeffs
    se = c.stderr
    pm = lambda key, scale=1.0: ("" if se.get(key) is None else f" ± {se[key] * scale:.3g}")  # noqa: E731
    lines = [f"  camera   f = ({k[0, 0]:.2f}{pm('fx')}, {k[1, 1]:.2f}{pm('fy')}) px, principal point "
             f"({k[0, 2]:.2f}{pm('cx')}, {k[1, 2]:.2f}{pm('cy')}) px, k1 = {d[0]:.4g}, k2 = {d[1]:.4g}",
             f"  tilt     τx = {math.degrees(d[12]):.4f}{pm('tau_x_deg')}°, τy = {math.degrees(d[13]):.4f}"
             f"{pm('tau_y_deg')}° ({c.tilt.get('mode')}"
             + (f": lens f = {c.tilt['lens_focal_length_mm']:.3f} mm" if 'lens_focal_length_mm' in c.tilt else "")
             + ")",
             f"  poses    {len(c.poses_used)} used, {len(c.poses_skipped)} skipped; reprojection "
             f"{c.reprojection_rms_px:.4f} px RMS"]
    if c.laser_plane is None:
        lines.append("  laser    none (no laser frames): a camera calibration only")
    else:
        pl = c.laser_plane
        lines.append(f"  laser    plane [{pl[0]:.6f}, {pl[1]:.6f}, {pl[2]:.6f}, {pl[3]:.4f}] (camera frame, mm), "
                     f"{c.laser_points} points, {c.laser_plane_rms_mm:.4f} mm RMS; σ normal "
                     f"{pm('laser_plane_normal_deg')[3:] or '–'}°, "
                     f"distance {pm('laser_plane_distance_mm')[3:] or '–'} mm")
    lines += _laser_pose_lines(res.laser_poses)
    if c.axis:
        lines.append(f"  axis     axis_mm = {c.axis['axis_mm']:.3f} mm ({c.axis['poses']} table poses; "
                     f"{c.axis['angle_to_sheet_deg']:.3f}° to the sheet, "
                     f"{c.axis['distance_to_sheet_mm']:.3f} mm off it)")
    return "\n".join(lines)


def _laser_pose_lines(laser_poses) -> list[str]:
    """One line per laser pose: points found, on the board, in the plane fit, and what was subtracted."""
    out = []
    for row in laser_poses:
        bg = row["background"][0].split(" (")[0] if row["background"] else "none"
        out.append(f"           pose {row['pose']}: {row['points_found']} found, {row['points_on_board']} on the "
                   f"pattern, {row['points_on_line']} on its line, {row['points_in_plane_fit'] or 0} in the plane fit; "
                   f"subtracted: {bg}")
    return out


def _run_target(args) -> int:
    from scheimpflug.app.progress import Progress
    from scheimpflug.calibration.target import calibrate_target_folder
    from scheimpflug.errors import CalibrationError
    from scheimpflug.io.atomic import write_json_atomic

    if not args.pattern:
        raise CalibrationError("--method target needs --pattern SPEC (e.g. chessboard:10x8:7)")
    folders = [args.dir] + ([args.on_table] if args.on_table else [])
    check_output(args.out, "--out", force=args.force, inputs=[args.rig], folders=folders)
    check_output(args.opencv, "--opencv", force=args.force, inputs=[args.rig, args.out], folders=folders)
    pitch = args.pixel_pitch_um
    if pitch is None and args.rig:
        from scheimpflug.model.rig import load_rig

        pitch = load_rig(args.rig).sensor.pixel_pitch_um
    folder = open_frames(args.dir, args)
    with Progress(0, label="calibrate", quiet=args.quiet) as bar:
        res = calibrate_target_folder(folder, args.pattern, tilt=args.tilt, pixel_pitch_um=pitch,
                                      distortion=args.distortion, refine=args.refine, detector=args.detector,
                                      stripe_along=args.stripe_along, table=args.on_table,
                                      f_number=args.f_number, laser_background=args.laser_background,
                                      progress=bar)
    for w in res.warnings:
        print(f"warning: {w}", file=sys.stderr)
    d = finite_json(res.calibration.to_json_dict())
    d["warnings"] = list(res.warnings)
    d["laser_poses"] = finite_json(list(res.laser_poses))
    d["nominal"] = finite_json(res.nominal)
    if args.out:
        write_json_atomic(args.out, d)
    if args.opencv:
        if res.calibration.laser_plane is None:
            raise CalibrationError("--opencv needs the laser plane: give laser frames of the pattern")
        from scheimpflug.calibration.opencv import write_opencv

        write_opencv(args.opencv, res.calibration, assumed=False)
    if args.json:
        print_json(d)
    else:
        print(_target_summary(res))
    return 0


def _run(args) -> int:
    if args.method == "target":
        return _run_target(args)
    from scheimpflug.app.progress import Progress
    from scheimpflug.calibration import CalibrationAccuracy
    from scheimpflug.io.atomic import write_json_atomic
    from scheimpflug.sheet_model import calibrate_sheet_folder

    acc = CalibrationAccuracy(hinge_px=args.accuracy_hinge_px, relative=args.accuracy_relative,
                              d0_resolution=args.accuracy_d0_resolution)
    check_output(args.out, "--out", force=args.force, inputs=[args.rig], folders=[args.dir])
    check_output(args.opencv, "--opencv", force=args.force, inputs=[args.rig, args.out], folders=[args.dir])
    check_plot(args.plot, force=args.force, inputs=[args.rig, args.out, args.opencv], folders=[args.dir])
    folder = open_frames(args.dir, args)
    f_mm, p_um, assumed = _optics(args, folder)
    with warnings.catch_warnings(), Progress(0, label="calibrate", quiet=args.quiet) as bar:
        warnings.simplefilter("ignore")
        model, method = ("general", "best") if args.method == "general" else (args.model, args.method)
        res = calibrate_sheet_folder(folder, args.plate_height_mm, model=model, method=method,
                                     detector=args.detector, focal_length_mm=f_mm if args.rig else None,
                                     pixel_pitch_um=p_um if args.rig else None,
                                     progress=bar, accuracy=acc)
    for name, reason in res.paper.skipped:
        print(f"warning: {name}: skipped: {reason}", file=sys.stderr)
    if res.paper.partial:
        names = ", ".join(f"{f} (no {edge} edge)" for f, edge in res.paper.partial)
        print(f"note: {len(res.paper.partial)} frame(s) show one plate edge only; they give the distance "
              f"relation and that edge: {names}", file=sys.stderr)
    for w in res.paper.warnings + res.paper.best.warnings:
        print(f"warning: {w}", file=sys.stderr)
    if assumed and (args.opencv or res.chosen is res.general):
        print(f"warning: the manifest's rig lacks the focal length or the pixel pitch: the camera intrinsics "
              f"use f = {f_mm:g} mm and a {p_um:g} µm pixel pitch, the missing one assumed (give --rig)",
              file=sys.stderr)
    d = _result_dict(res)
    d["warnings"] = list(res.paper.warnings) + list(d.get("warnings", []))
    if args.out:
        write_json_atomic(args.out, finite_json(d))     # undefined numbers as null
    if args.opencv:
        from scheimpflug.calibration.opencv import write_opencv

        write_opencv(args.opencv, res.chosen, f_mm, p_um, assumed)
    if args.plot:
        from scheimpflug.app.calibration_plot import plot_calibration
        plot_calibration(res.paper, args.plot)
    if args.json:
        d["skipped"] = [{"file": f, "reason": r} for f, r in res.paper.skipped]
        d["one_edge"] = [{"file": f, "missing": e} for f, e in res.paper.partial]
        print_json(d)
    else:
        print(_summary(res))
    return 0
