"""The VDI/VDE 2634-2 acceptance test in the twin: scan plan, rendering, evaluation.

How an artefact is scanned
--------------------------
A light-sheet profiler measures one profile per frame; this instrument's own
scan is the rotary stage, so every artefact is measured as a **rotary scan**:
it stands off the axis on the turntable and turns through the sheet, and the
profiles, rotated back by their stage angle, make its point cloud
(:mod:`scheimpflug.reconstruct`).  Only the angles at which the artefact
crosses the sheet on the laser's side are rendered: an artefact whose centre
is at radius ``r`` from the axis crosses at θ ≈ 0 (we place it on the −x side
of the part frame), for ``|θ| ≲ asin((R + 1 mm)/r)``.  An artefact centred on
the axis would show every frame the same section, so none is.

The measuring volume is the cylinder about the rotary axis seen on both sides
of it (:func:`scheimpflug.acceptance.measuring_volume_diagonal`, from the rig's
closed forms); ``L0`` its diagonal.  Artefacts (VDI/VDE 2634-2 §5):

* sphere Ø 0.1·L0 (the guideline allows 0.1–0.2) on a post, in 10 positions:
  radii from 0.25 to 1 of the largest that keeps it inside, heights low, mid,
  high;
* ball bar: two spheres Ø 0.1·L0, centre distance 0.35·L0 (≥ 0.3), posed
  tangentially (both spheres in view, neither shadowing the other), 7
  positions: radii, heights and inclinations of ±30–45°;
* plane: a plate 0.55·L0 long (≥ 0.5), 0.3·L0 high, its face toward the laser,
  6 positions: heights, turned ±20° about the vertical, inclined ±15°.

Segmentation uses the nominal pose (this is the twin): sphere points within
``R + 1 mm`` of the nominal centre and above the post's joint (the lowest
0.2·R of the sphere is left out), plane points within 1 mm of the nominal face
and 2 mm inside its edges.  ``quick=True`` keeps 2 sphere positions, 1 ball
bar and 1 plane with fewer frames (tests); the full plan is the guideline's.

Point quality: every point carries its measured quality (stripe width, SNR,
laser and camera incidence, sweep edge; :mod:`scheimpflug.point_quality`,
from the frames and the calibration only), and the headline figures are those
of the points that pass the filter (default
:data:`scheimpflug.point_quality.DEFAULT_FILTER`, as ``reconstruct`` writes
them); the figures of every point are reported beside them as ``unfiltered``.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scheimpflug import acceptance as vdi
from scheimpflug.axis import locate_axis
from scheimpflug.budget import sheet_shift_mm
from scheimpflug.callbacks import ProgressCallback, report
from scheimpflug.errors import CalibrationError
from scheimpflug.io.frames import open_frame_folder
from scheimpflug.model.binning import binned_rig
from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.rig import Rig
from scheimpflug.point_quality import (
    DEFAULT_FILTER,
    QualityFilter,
    SheetGeometry,
    assess_points,
    filter_counts,
    quality_mask,
    sheet_geometry,
    sweep_edges,
)
from scheimpflug.reconstruct import extract_folder_stripes, reconstruct_profiles
from scheimpflug.sheet_model import calibrate_sheet_folder

from .scenarios import Scenario, _rotary_frames
from .stages import stage_from_part

#: The artefacts' surface: diffuse, as VDI/VDE 2634-2 asks of its artefacts (a near-specular metal
#: sphere biases the stripe centre at oblique incidence by up to a pixel in the twin).
_MATERIAL = "cardboard"

__all__ = [
    "ArtefactPosition",
    "acceptance_by_calibration",
    "acceptance_plan",
    "calibration_constants",
    "measured_cloud",
    "measuring_volume",
    "position_scenario",
    "run_acceptance",
    "score_position",
]


@dataclass(frozen=True, eq=False)
class ArtefactPosition:
    """One artefact in one position, with the angles that scan it.

    Parameters
    ----------
    kind : str
        "sphere", "ball_bar" or "plane".
    index : int
        Position number within its kind.
    part_from_own : (4, 4) float
        Pose of the artefact's own frame in the part (turntable) frame [mm].
    angles_deg : tuple of float
        Stage angles to render [deg].
    nominal : dict
        Calibrated dimensions: ``diameter_mm``, ``distance_mm`` (ball bar),
        ``length_mm``/``height_mm`` (plane) [mm].
    """

    kind: str
    index: int
    part_from_own: np.ndarray
    angles_deg: tuple
    nominal: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        """``kind-NN`` [-]."""
        return f"{self.kind}-{self.index:02d}"


def measuring_volume(rig: Rig) -> dict:
    """The rig's measuring volume (closed forms): ``L0_mm``, ``radius_mm``, ``height_mm``, ``z_mm``.

    Parameters
    ----------
    rig : Rig
        The instrument.

    Returns
    -------
    dict
        :func:`scheimpflug.acceptance.measuring_volume_diagonal` plus ``z_mm``, the volume's
        [bottom, top] in the part frame (z = 0 on the turntable) [mm].
    """
    g, s = hinge_geometry(rig), rig.sensor
    d0, axis = rig.stage.d0_mm, rig.stage.axis_mm
    near, far = sorted(g.distance_from_column([0.0, s.columns - 1.0]) + d0)
    per = s.rows * g.C_mm / abs(g.F2_px_mm)
    R = min(axis - near, far - axis)
    vol = vdi.measuring_volume_diagonal(near, far, axis, per, axis - R - d0)
    k = g.C_mm * (axis - R - d0) / abs(g.F2_px_mm)             # mm of height per row there
    z_lo, z_hi = -(s.rows - 1 - s.axis_row) * k, s.axis_row * k
    return {**vol, "z_mm": [z_lo - rig.stage.rotary_table_z_mm, z_hi - rig.stage.rotary_table_z_mm]}


def _rot_x(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    m = np.eye(4)
    m[1:3, 1:3] = [[c, -s], [s, c]]
    return m


def _rot_y(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    m = np.eye(4)
    m[0, 0], m[0, 2], m[2, 0], m[2, 2] = c, s, -s, c
    return m


def _rot_z(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    return m


def _move(x, y, z) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def _window(centres_yx, radius_mm: float, n: int) -> tuple:
    """Angles [deg] at which spheres at part-frame (y, −r) cross the sheet, n per sphere."""
    out = []
    for y, r in centres_yx:
        rho = math.hypot(y, r)
        mid = math.degrees(math.atan2(y, r))
        w = math.degrees(math.asin(min(1.0, (radius_mm + 1.0) / rho)))
        out += list(np.linspace(mid - w, mid + w, n))
    return tuple(float(a) for a in sorted(out))


def _sphere_positions(vol: dict, D: float, n_frames: int, quick: bool) -> list:
    R, (z_lo, z_hi) = D / 2, vol["z_mm"]
    r_max = vol["radius_mm"] - R - 2.0
    table = [(0.25, 0.5), (0.5, 0.2), (0.5, 0.8), (0.75, 0.35), (0.75, 0.65), (1.0, 0.2), (1.0, 0.5),
             (1.0, 0.8), (0.35, 0.8), (0.35, 0.2)]
    table = [table[6], table[2]] if quick else table
    out = []
    for i, (fr, fz) in enumerate(table):
        r = max(fr * r_max, R + 8.0)
        zc = z_lo + R + 2 + fz * (z_hi - z_lo - D - 4)
        pose = _move(-r, 0.0, zc - R)             # sphere generator: centre at stand + R
        out.append(ArtefactPosition("sphere", i, pose, _window([(0.0, r)], R, n_frames),
                                    {"diameter_mm": D, "centre_mm": [-r, 0.0, zc]}))
    return out


def _bar_positions(vol: dict, D: float, L: float, n_frames: int, quick: bool) -> list:
    R, (z_lo, z_hi) = D / 2, vol["z_mm"]
    r_max = math.sqrt(max((vol["radius_mm"] - R - 2) ** 2 - (L / 2) ** 2, 1.0))
    zm = 0.5 * (z_lo + z_hi)
    table = [(0.6, 0.5, 0.0), (0.95, 0.5, 0.0), (0.6, 0.25, 0.0), (0.6, 0.75, 0.0), (0.6, 0.5, 35.0),
             (0.6, 0.5, -35.0), (0.95, 0.5, 25.0)]
    table = table[:1] if quick else table
    out = []
    for i, (fr, fz, tilt) in enumerate(table):
        r = max(fr * r_max, R + 8.0)
        zc = z_lo + R + 2 + fz * (z_hi - z_lo - D - 4) - zm
        # own frame: centres (±L/2, 0, stand + R) with stand 0; turn to tangential, incline, place
        pose = _move(-r, 0.0, zm + zc) @ _rot_x(tilt) @ _rot_z(90.0) @ _move(0.0, 0.0, -R)
        c = np.array([[-L / 2, 0, R, 1.0], [L / 2, 0, R, 1.0]]) @ pose.T
        angles = _window([(c[0, 1], -c[0, 0]), (c[1, 1], -c[1, 0])], R, n_frames)
        out.append(ArtefactPosition("ball_bar", i, pose, angles,
                                    {"diameter_mm": D, "distance_mm": L, "centres_mm": c[:, :3].tolist()}))
    return out


def _plane_positions(vol: dict, L: float, H: float, n_frames: int, quick: bool) -> list:
    z_lo, z_hi = vol["z_mm"]
    e = min(0.65 * vol["radius_mm"], math.sqrt(max(vol["radius_mm"] ** 2 - (L / 2) ** 2, 1.0)) - 3)
    table = [(0.5, 0.0, 0.0), (0.3, 0.0, 0.0), (0.7, 0.0, 0.0), (0.5, 20.0, 0.0), (0.5, -20.0, 0.0),
             (0.5, 0.0, 15.0)]
    table = table[:1] if quick else table
    out = []
    for i, (fz, yaw, tilt) in enumerate(table):
        z0 = z_lo + 2 + fz * max(z_hi - z_lo - H - 4, 0.0)
        # own frame: face x = 0, y ∈ ±L/2, z ∈ [0, H]; tilt about the face's horizontal centre line
        pose = _move(-e, 0.0, z0 + H / 2) @ _rot_z(yaw) @ _rot_y(tilt) @ _move(0.0, 0.0, -H / 2)
        ends = [pose @ [0.0, t, H / 2, 1.0] for t in (-(L / 2 - 3), L / 2 - 3)]
        lo, hi = sorted(math.degrees(math.atan2(p[1], -p[0])) for p in ends)
        angles = tuple(float(a) for a in np.linspace(lo, hi, n_frames))
        out.append(ArtefactPosition("plane", i, pose, angles, {"length_mm": L, "height_mm": H}))
    return out


def acceptance_plan(rig: Rig, quick: bool = False, frames: int | None = None,
                    kinds=None) -> tuple[dict, list]:
    """The measuring volume and every artefact position of the test (module docstring).

    Parameters
    ----------
    rig : Rig
        The instrument (geometry only).
    quick : bool
        A reduced plan for tests (2 spheres, 1 ball bar, 1 plane).
    frames : int, optional
        Frames per sphere crossing / per plane scan (default 9 quick, 21 full).
    kinds : iterable of str, optional
        Keep only these kinds (``sphere``, ``ball_bar``, ``plane``); default all.

    Returns
    -------
    volume : dict
        :func:`measuring_volume`, plus the artefact sizes ``sphere_diameter_mm``,
        ``bar_distance_mm``, ``plane_length_mm``, ``plane_height_mm``.
    positions : list of ArtefactPosition
        Spheres, ball bars, planes.
    """
    vol = measuring_volume(rig)
    L0 = vol["L0_mm"]
    D, Lb, Lp, Hp = 0.1 * L0, 0.35 * L0, 0.55 * L0, 0.3 * L0
    n = frames or (9 if quick else 21)
    vol.update(sphere_diameter_mm=D, bar_distance_mm=Lb, plane_length_mm=Lp, plane_height_mm=Hp)
    pos = (_sphere_positions(vol, D, n, quick) + _bar_positions(vol, D, Lb, n, quick)
           + _plane_positions(vol, Lp, Hp, n, quick))
    if kinds is not None:
        pos = [p for p in pos if p.kind in set(kinds)]
    return vol, pos


def _assembly(position: ArtefactPosition, material: str = _MATERIAL):
    from scenes.generators import ball_bar, plate, sphere
    from scenes.part import Assembly

    nom = position.nominal
    if position.kind == "sphere":
        part = sphere(nom["diameter_mm"], stand_height_mm=position.part_from_own[2, 3], material=material)
        part = part.transformed(_move(*position.part_from_own[:2, 3], 0.0))
    elif position.kind == "ball_bar":
        part = ball_bar(nom["diameter_mm"], nom["distance_mm"], stand_height_mm=0.0,
                        post_diameter_mm=0.3 * nom["diameter_mm"], material=material)
        part = part.transformed(position.part_from_own)
    else:
        part = plate(width_mm=nom["length_mm"], height_mm=nom["height_mm"],
                     material=material).transformed(position.part_from_own)
    return Assembly(position.name, (part,))


def position_scenario(rig: Rig, position: ArtefactPosition, seed: int = 0,
                      material: str = _MATERIAL) -> Scenario:
    """The rotary-scan scenario of one artefact position (truth: stripe only, no pixel maps).

    Parameters
    ----------
    rig : Rig
        The instrument.
    position : ArtefactPosition
        Artefact, pose and angles.
    seed : int
        Run seed.
    material : str
        Material tag of the artefact (default diffuse cardboard, as the guideline asks).

    Returns
    -------
    Scenario
        Renderable with :func:`sim.writer.render_scenario`.
    """
    asm = _assembly(position, material)
    params = {"part": position.name, "kind": position.kind, "nominal": position.nominal,
              "part_from_own": np.asarray(position.part_from_own).tolist(),
              "angles_deg": list(position.angles_deg)}
    return Scenario("rotary", params, asm, _rotary_frames(rig, seed, position.angles_deg),
                    stage_from_part(rig, 0.0), truth_pixels_every=0)


# ------------------------------------------------------------------ rendering and evaluation


def _render(rig: Rig, scenario: Scenario, out: Path, seed: int, spp, warn) -> None:
    from .writer import MitsubaTwin, build_manifest, generator_info, render_scenario

    twin = MitsubaTwin(rig, scenario.assembly, spp=spp)
    manifest = build_manifest(rig, scenario, seed, twin.spp, twin.variant, generator_info(), twin.describe())
    render_scenario(rig, scenario, out, twin, manifest, warn=warn)


def _segment(position: ArtefactPosition, xyz: np.ndarray):
    """The measured points that belong to the artefact's measured surfaces (module docstring)."""
    nom = position.nominal
    if position.kind == "sphere":
        c, R = np.array(nom["centre_mm"]), nom["diameter_mm"] / 2
        d = np.linalg.norm(xyz - c, axis=1)
        return xyz[(d < R + 1.0) & (xyz[:, 2] > c[2] - 0.8 * R)]
    if position.kind == "ball_bar":
        R = nom["diameter_mm"] / 2
        out = []
        for c in np.array(nom["centres_mm"]):
            d = np.linalg.norm(xyz - c, axis=1)
            own = (xyz - c) @ position.part_from_own[:3, :3]            # bar frame: post along −z
            out.append(xyz[(d < R + 1.0) & (own[:, 2] > -0.8 * R)])
        return out
    own = (xyz - position.part_from_own[:3, 3]) @ position.part_from_own[:3, :3]
    L, H = nom["length_mm"], nom["height_mm"]
    keep = ((np.abs(own[:, 0]) < 1.0) & (np.abs(own[:, 1]) < L / 2 - 2)
            & (own[:, 2] > 2) & (own[:, 2] < H - 2))
    return xyz[keep]


def _evaluate(position: ArtefactPosition, pts, exclude_fraction: float) -> dict:
    nom = position.nominal
    if position.kind == "sphere":
        return vdi.probing_errors(pts, nom["diameter_mm"], exclude_fraction)
    if position.kind == "ball_bar":
        return vdi.sphere_spacing_error(pts[0], pts[1], nom["distance_mm"], exclude_fraction)
    return vdi.flatness_error(pts, exclude_fraction)


def _extraction_errors(ff, rows, us, truth_constants) -> np.ndarray:
    """Signed in-sheet error [mm] of every matched stripe point against the exact centres."""
    out = []
    for i, (r, u) in enumerate(zip(rows, us)):
        tu = np.load(ff.path / "truth" / f"{i:05d}.npz")["stripe_u"]
        t = tu[np.asarray(r, np.int64)]
        ok = np.isfinite(t) & (np.abs(u - t) <= 3.0)
        du = u[ok] - t[ok]
        dd, dh = sheet_shift_mm(du, t[ok], np.asarray(r, float)[ok], truth_constants)
        out.append(np.sign(du) * np.hypot(dd, dh))
    return np.concatenate(out) if out else np.zeros(0)


def score_position(rig: Rig, position: ArtefactPosition, cloud, exclude_fraction: float) -> tuple[dict, object]:
    """Segment a position's reconstructed cloud with the nominal pose and evaluate it.

    Parameters
    ----------
    rig : Rig
        The instrument (its stage frame defines the cloud's frame).
    position : ArtefactPosition
        The artefact and its nominal pose.
    cloud : scheimpflug.reconstruct.PointCloud
        The reconstructed rotary scan (stage frame at θ = 0).
    exclude_fraction : float
        Outlier fraction excluded [-].

    Returns
    -------
    result : dict
        ``name``, ``kind`` and the quality parameters of the position.
    points : ndarray or list of ndarray
        The artefact's points in the part frame (two sets for a ball bar) [mm].

    Raises
    ------
    ScheimpflugError
        When fewer than 20 points fall on the artefact (it is not in view of this rig).
    """
    ref_from_part = stage_from_part(rig, 0.0)          # the cloud's frame: the stage frame at θ = 0
    pts = _segment(position, (cloud.xyz_mm - ref_from_part[:3, 3]) @ ref_from_part[:3, :3])
    sizes = [len(p) for p in pts] if isinstance(pts, list) else [len(pts)]
    if min(sizes) < 20:
        from scheimpflug.errors import ScheimpflugError
        raise ScheimpflugError(f"acceptance: {position.name} gave only {min(sizes)} points on the artefact "
                               f"(is it in view of this rig?)")
    return {"name": position.name, "kind": position.kind, **_evaluate(position, pts, exclude_fraction)}, pts


def acceptance_by_calibration(rig: Rig, out, calibrations: dict, *, binning: int = 1, quick: bool = True,
                              frames: int | None = None, seed: int = 0,
                              exclude_fraction: float = vdi.EXCLUDE_FRACTION,
                              quality: QualityFilter | None = DEFAULT_FILTER,
                              log: Callable[[str], None] | None = None) -> dict:
    """The acceptance test's figures of several given calibrations, on one rendering of the artefacts.

    Each position (:func:`acceptance_plan`) is rendered once and reconstructed with every
    calibration; no calibration frames are rendered (``sim.calibration_choice`` makes them).

    Parameters
    ----------
    rig : Rig
        The instrument (full size; binned here).
    out : path
        Working folder: one frame folder per position.
    calibrations : dict
        Name → ``(sheet model, axis_mm)``; ``axis_mm`` None: the calibration's own 3-D axis
        (:func:`scheimpflug.reconstruct.points_from_pixels`).
    binning : int, default 1
        k × k binned sensor.
    quick : bool, default True
        The reduced plan.
    frames : int, optional
        Frames per crossing.
    seed : int, default 0
        Run seed.
    exclude_fraction : float
        Outlier fraction excluded per measurement [-].
    quality : QualityFilter or None
        The point-quality filter (default the pipeline's); None: every point.
    log : callable, optional
        Receives one line per position.

    Returns
    -------
    dict
        Name → ``PF_mm``, ``PS_mm``, ``SD_mm``, ``F_mm`` (the system's figures, with the filter),
        ``L0_mm`` and ``positions`` (per position's figures); a position a calibration could not
        measure (too few points on the artefact) is named under ``failed``.
    """
    from scheimpflug.errors import ScheimpflugError

    out = Path(out)
    rig_b = binned_rig(rig, binning)
    vol, plan = acceptance_plan(rig_b, quick, frames)
    rows = {name: {"sphere": [], "ball_bar": [], "plane": [], "failed": []} for name in calibrations}
    geometry = {name: _geometry(model, rig_b, lambda msg: None) for name, (model, _) in calibrations.items()}
    for pos in plan:
        if log:
            log(f"acceptance: {pos.name}")
        _render(rig_b, position_scenario(rig_b, pos, seed, _MATERIAL), out / pos.name, seed, None,
                lambda msg: None)
        ff = open_frame_folder(out / pos.name)
        stripes = extract_folder_stripes(ff, "cog")          # once: the same detection for every calibration
        for name, (model, axis_mm) in calibrations.items():
            cloud, _ = measured_cloud(ff, model, axis_mm, geometry[name], stripes=stripes)
            if quality is not None:
                cloud = cloud.select(quality_mask(cloud, quality))
            try:
                res, _ = score_position(rig_b, pos, cloud, exclude_fraction)
            except ScheimpflugError as exc:
                rows[name]["failed"].append(f"{pos.name}: {exc}")
                continue
            rows[name][pos.kind].append(res)
    return {name: {**vdi.summarize(r["sphere"], r["ball_bar"], r["plane"], vol["L0_mm"]),
                   "positions": {k: r[k] for k in ("sphere", "ball_bar", "plane")}, "failed": r["failed"]}
            for name, r in rows.items()}


def measured_cloud(ff, cal, axis_mm: float | None, geometry: SheetGeometry, stripes=None):
    """The cloud of a rotary scan folder with every point's measured quality (frames and calibration only).

    Parameters
    ----------
    ff : scheimpflug.io.frames.FrameFolder
        The scan.
    cal : SheetModel
        The calibration.
    axis_mm : float or None
        Stage coordinate of the rotary axis [mm]; None: the calibration's own 3-D axis (its
        ``axis_mm`` places it for the incidence angles).
    geometry : scheimpflug.point_quality.SheetGeometry or None
        Laser origin and camera centre (:func:`scheimpflug.point_quality.sheet_geometry`);
        None: the incidences stay unknown (NaN), the sweep edges are still measured.
    stripes : scheimpflug.reconstruct.FolderStripes, optional
        The scan's stripe samples when already extracted (default: extracted here, "cog").

    Returns
    -------
    cloud : scheimpflug.reconstruct.PointCloud
        Every point, with its width, SNR, incidences and sweep edge.
    stripes : scheimpflug.reconstruct.FolderStripes
        The stripe samples it was made of.
    """
    st = stripes if stripes is not None else extract_folder_stripes(ff, "cog")
    cloud = reconstruct_profiles(st.rows, st.u, [r.angle_deg for r in ff.frames], cal, axis_mm,
                                 intensity=st.peak, snr=st.snr, stripe_width_px=st.stripe_width_px,
                                 along=st.along)
    if geometry is None:
        edge = sweep_edges(cloud.frame, cloud.row, len(ff), cloud.intensity)
        return dataclasses.replace(cloud, sweep_edge=edge), st
    in_sheet = axis_mm if axis_mm is not None else float(cal.axis["axis_mm"])
    return assess_points(cloud, geometry, in_sheet, len(ff)), st


def _geometry(calibration, rig_b: Rig, warn) -> SheetGeometry | None:
    """The sheet geometry of the point quality, or None (and a warning) when the calibration has none."""
    try:
        return sheet_geometry(calibration, rig_b.lens.focal_length_mm, rig_b.sensor.pixel_pitch_um,
                              rig_b.laser.origin_x_mm)
    except (CalibrationError, ValueError) as exc:
        warn(f"point quality: incidence angles not measured ({exc})")
        return None


def _figures(res: dict) -> dict:
    return {k: res[k] for k in ("PF_mm", "PS_mm", "SD_mm", "F_mm", "n_points") if k in res}


def _scan(rig, position, out: Path, cal, axis_mm, seed, spp, warn, exclude_fraction, truth_constants,
          material, geometry, quality):
    _render(rig, position_scenario(rig, position, seed, material), out, seed, spp, warn)
    ff = open_frame_folder(out)
    cloud, st = measured_cloud(ff, cal, axis_mm, geometry)
    raw, raw_pts = score_position(rig, position, cloud, exclude_fraction)
    if quality is None:
        res, pts = raw, raw_pts
    else:
        res, pts = score_position(rig, position, cloud.select(quality_mask(cloud, quality)), exclude_fraction)
        res["quality_filter"] = filter_counts(cloud, quality)
    res["unfiltered"] = _figures(raw) if raw.get("kind") != "ball_bar" else {
        "SD_mm": raw["SD_mm"], "n_points": raw["sphere_a"]["n_points"] + raw["sphere_b"]["n_points"]}
    res["n_frames"] = len(ff)
    return res, pts, _extraction_errors(ff, st.rows, st.u, truth_constants)


def _calibrate(rig, out: Path, model: str, seed, spp, warn, calibration_options):
    from .writer import render_folder

    render_folder(rig, "calibration", out / "calibration", seed=seed, spp=spp, warn=warn, truth_pixels_every=0,
                  **(calibration_options or {}))
    res = calibrate_sheet_folder(out / "calibration", model=model,
                                 focal_length_mm=rig.lens.focal_length_mm,
                                 pixel_pitch_um=rig.sensor.pixel_pitch_um)
    render_folder(rig, "blocker", out / "blocker", seed=seed, spp=spp, warn=warn, truth_pixels_every=0)
    return res, locate_axis(out / "blocker", res.chosen).axis_mm


def calibration_constants(calibration) -> dict:
    """The paper-form constants of a calibration, JSON-ready.

    Parameters
    ----------
    calibration : scheimpflug.calibration.Calibration
        A paper-form calibration (for the general model: its ``paper`` start).

    Returns
    -------
    dict
        ``hinge_u_px``, ``hinge_v_px`` [px], ``F2_px_mm`` [px·mm], ``d0_mm``, ``C_mm`` [mm].
    """
    return {k: float(getattr(calibration, k)) for k in ("hinge_u_px", "hinge_v_px", "F2_px_mm", "d0_mm", "C_mm")}


def _range_excluding(e: np.ndarray, fraction: float) -> float:
    """Range of ``e`` after dropping the ⌊fraction·n⌋ values farthest from the median (as PF and F)."""
    k = int(fraction * e.size)
    keep = np.sort(np.argsort(np.abs(e - np.median(e)))[: e.size - k])
    return float(np.ptp(e[keep]))


def run_acceptance(rig: Rig, out, *, model: str = "auto", binning: int = 1, quick: bool = False,
                   frames: int | None = None, seed: int = 0, spp: int | None = None,
                   exclude_fraction: float = vdi.EXCLUDE_FRACTION, kinds=None, material: str = _MATERIAL,
                   plan_rig: Rig | None = None, calibration_options: dict | None = None,
                   quality: QualityFilter | None = DEFAULT_FILTER,
                   progress: ProgressCallback | None = None,
                   warn: Callable[[str], None] | None = None) -> dict:
    """Render, reconstruct and evaluate the whole acceptance test (module docstring).

    Parameters
    ----------
    rig : Rig
        The instrument, with its realism (noise, speckle, misalignment, distortion).
    out : path
        Working folder: ``calibration/``, ``blocker/``, one frame folder per position.
    model : {"paper", "general", "auto"}
        Calibration model (:func:`scheimpflug.sheet_model.calibrate_sheet_folder`).
    binning : int
        k × k binned sensor (same geometry).
    quick : bool
        Reduced plan (:func:`acceptance_plan`).
    frames : int, optional
        Frames per crossing.
    seed : int
        Run seed.
    spp : int, optional
        Laser samples per sensor row.
    exclude_fraction : float
        Outlier fraction excluded per measurement (0.003 = the guideline's; 0 = none) [-].
    kinds : iterable of str, optional
        Scan only these kinds (``sphere``, ``ball_bar``, ``plane``); default all.
    material : str
        The artefacts' material tag (default diffuse cardboard, as the guideline asks).
    plan_rig : Rig, optional
        The rig whose closed forms place the artefacts (a design whose as-built copy is
        measured); default ``rig``.  Full size: it is binned like ``rig``.
    calibration_options : dict, optional
        Options of the calibration scenario (``steps``, ``step_mm``, ``start_mm``,
        ``plate_height_mm``); default the scenario's.
    quality : QualityFilter or None
        The point-quality filter applied before the evaluation (default
        :data:`scheimpflug.point_quality.DEFAULT_FILTER`); None evaluates every point.
    progress : ProgressCallback, optional
        ``progress(done, total)`` per scan.
    warn : callable, optional
        Receives warnings (default stderr).

    Returns
    -------
    dict
        ``PF_mm``, ``PS_mm``, ``SD_mm``, ``F_mm``, ``L0_mm`` (the table, the headline: with the
        quality filter), ``unfiltered`` (the same table of every point, PF, PS, SD, F),
        ``quality_filter`` (its thresholds, or None), ``positions`` (per-position
        detail, each with its ``unfiltered`` figures and the filter's ``quality_filter`` counts),
        ``volume``, ``calibration`` (model, selection), ``axis_mm``, ``extraction_range_mm``
        and ``extraction_rms_mm`` (the stripe-extraction error mapped to the sheet against the exact
        stripe centres: its range, with the same exclusion as PF and F, and its RMS),
        ``exclude_fraction``, ``points`` (per position, for plots; not JSON) and ``sheet_model``
        (the chosen calibration object; not JSON).  ``calibration`` also holds ``constants``,
        the paper-form constants (:func:`calibration_constants`).
    """
    warn = warn or (lambda msg: print(f"warning: {msg}", file=sys.stderr))
    out = Path(out)
    rig_b = binned_rig(rig, binning)
    vol, plan = acceptance_plan(binned_rig(plan_rig or rig, binning), quick, frames, kinds)
    report(progress, 0, len(plan) + 1)
    cal_res, axis_mm = _calibrate(rig_b, out, model, seed, spp, warn, calibration_options)
    geometry = _geometry(cal_res.chosen, rig_b, warn)
    g = hinge_geometry(rig_b)
    truth = {"hinge_u_px": g.hinge_column, "hinge_v_px": g.axis_row, "F2_px_mm": g.F2_px_mm, "C_mm": g.C_mm}
    rows, points, errs = {"sphere": [], "ball_bar": [], "plane": []}, {}, []
    for k, pos in enumerate(plan):
        report(progress, k + 1, len(plan) + 1)
        res, pts, e = _scan(rig_b, pos, out / pos.name, cal_res.chosen, axis_mm, seed, spp, warn,
                            exclude_fraction, truth, material, geometry, quality)
        rows[pos.kind].append(res)
        points[pos.name] = pts
        errs.append(e)
    report(progress, len(plan) + 1, len(plan) + 1)
    e = np.concatenate(errs) if errs else np.zeros(0)
    table = vdi.summarize(rows["sphere"], rows["ball_bar"], rows["plane"], vol["L0_mm"])
    raw = vdi.summarize(*[[r["unfiltered"] for r in rows[k]] for k in ("sphere", "ball_bar", "plane")],
                        vol["L0_mm"])
    chosen = "general" if cal_res.chosen is cal_res.general else "paper"
    return {**table, "unfiltered": {k: raw[k] for k in ("PF_mm", "PS_mm", "SD_mm", "F_mm")},
            "quality_filter": None if quality is None else quality.to_json_dict(), "volume": vol,
            "positions": rows, "axis_mm": float(axis_mm), "binning": binning,
            "calibration": {"model": chosen, "selection": cal_res.selection.to_json_dict(),
                            "constants": calibration_constants(cal_res.paper.best)},
            "extraction_range_mm": _range_excluding(e, exclude_fraction) if e.size else None,
            "extraction_rms_mm": float(np.sqrt(np.mean(e ** 2))) if e.size else None,
            "exclude_fraction": exclude_fraction, "points": points, "sheet_model": cal_res.chosen}
