"""The twin's frames of a printed pattern at the poses real frames show (issue 36 item 6).

A camera-and-sheet scanner's calibration frames show its pattern at poses a person (or a
turntable) chose; to compare the twin's laser line on the pattern with the real one, the twin
renders the same pattern at the same poses.  :func:`rig_from_camera_poses` maps a pose in
the calibration's OpenCV camera frame (:func:`scheimpflug.board_laser.board_pose`) into the
rig frame of a rig built from that calibration (``scheimpflug rig from-calibration``: the
instrument frame is the calibration's camera frame, so the rig's own OpenCV camera frame,
:func:`sim.truth.opencv_camera`, is that frame); :func:`render_poses` renders the ``target``
scenario at those poses (:func:`sim.target.target_scenario` with ``rig_from_patterns``).

What the stripe on the board depends on: its position, only on the line where the laser's
plane meets the board (any plane through that line draws the same stripe there); its width,
on the sheet's thickness where it meets the board (waist, divergence, the distance from the
emitter) and on the angle between the sheet and the board; its level, on power × exposure,
the fan's spread and the print's reflectance.

:func:`fit_waist_and_power` identifies the two unknowns of a rig the stripe's width and level
depend on most — ``[laser] waist_um`` and ``power_mw`` (power × exposure: the exposure stays) —
from one real frame's stripe: the values at which the twin's frame at that pose gives the real
frame's FWHM and peak level (Newton's method in log waist and log power, the Jacobian by finite
differences of 5 %, each step one render of one frame; the twin's Monte Carlo and sensor noise
fixed by the seed).  What the fit does not see — the other frames — is the check.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scheimpflug.model.rig import Rig

__all__ = ["StripeFit", "fit_waist_and_power", "render_poses", "rig_from_camera_poses"]


def rig_from_camera_poses(rig: Rig, camera_from_patterns) -> list[np.ndarray]:
    """Poses in the rig's OpenCV camera frame → the rig frame.

    Parameters
    ----------
    rig : Rig
        A rig whose OpenCV camera frame is the poses' frame (one built from their calibration).
    camera_from_patterns : sequence of (4, 4) array_like float
        The pattern frame in the camera frame, per pose [mm].

    Returns
    -------
    list of (4, 4) ndarray float64
        ``rig_from_pattern`` per pose [mm].
    """
    from .truth import opencv_camera

    _, camera_from_rig = opencv_camera(rig)
    rig_from_camera = np.linalg.inv(camera_from_rig)
    return [rig_from_camera @ np.asarray(m, np.float64) for m in camera_from_patterns]


def render_poses(rig: Rig, camera_from_patterns, out, pattern: str, *, lights=("laser",), seed: int = 0,
                 spp: int | None = None, progress=None, warn=None, **options):
    """Render the ``target`` scenario with the pattern at given poses.

    Parameters
    ----------
    rig : Rig
        The instrument (:func:`rig_from_camera_poses`).
    camera_from_patterns : sequence of (4, 4) array_like float
        The poses in the rig's OpenCV camera frame [mm].
    out : path
        Frame folder to write.
    pattern : str
        Pattern spec (``chessboard:11x6:13``).
    lights : sequence of str, default ("laser",)
        Frames per pose (:data:`sim.target.TARGET_LIGHTS`).
    seed : int, default 0
        Run seed.
    spp : int, optional
        Laser samples per sensor row.
    progress, warn : callable, optional
        As :func:`sim.writer.render_folder`.
    **options
        Other options of :func:`sim.target.target_scenario` (``plate_mm``, ``border_mm`` …).

    Returns
    -------
    (RenderStats, dict)
        As :func:`sim.writer.render_folder`.
    """
    from .writer import render_folder

    poses = rig_from_camera_poses(rig, camera_from_patterns)
    return render_folder(rig, "target", out, seed=seed, spp=spp, progress=progress, warn=warn,
                         pattern=pattern, lights=tuple(lights), rig_from_patterns=poses, **options)


@dataclass(frozen=True)
class StripeFit:
    """The waist and power that reproduce a real stripe's width and level (:func:`fit_waist_and_power`).

    Parameters
    ----------
    waist_um, power_mw : float
        The fitted ``[laser]`` keys [µm], [mW].
    fwhm_px, peak_dn : float
        The twin's figures at them [px], [DN].
    renders : int
        Frames rendered.
    converged : bool
        Both figures within ``tol`` of the targets.
    """

    waist_um: float
    power_mw: float
    fwhm_px: float
    peak_dn: float
    renders: int
    converged: bool


def fit_waist_and_power(rig: Rig, camera_from_pattern, pattern: str, measure, target_fwhm_px: float,
                        target_peak_dn: float, work, *, tol: float = 0.02, max_steps: int = 8,
                        seed: int = 0) -> StripeFit:
    """The ``[laser]`` waist and power whose twin frame gives a real stripe's FWHM and peak (module docstring).

    Parameters
    ----------
    rig : Rig
        The rig (its other keys stay).
    camera_from_pattern : (4, 4) array_like float
        The pose of the real frame (:func:`rig_from_camera_poses`) [mm].
    pattern : str
        Pattern spec.
    measure : callable
        ``measure(frame) -> (fwhm_px, peak_dn)`` of a twin frame as written ((rows, columns[, 3]) uint8):
        the same measurement as the real frame's.
    target_fwhm_px, target_peak_dn : float
        The real frame's figures [px], [DN].
    work : path
        A folder for the renders (one sub-folder per render).
    tol : float, default 0.02
        Relative tolerance on both figures [-].
    max_steps : int, default 8
        Newton steps at most.
    seed : int, default 0
        Render seed.

    Returns
    -------
    StripeFit
        The last (best) values; ``converged`` False when ``max_steps`` did not reach ``tol``.
    """
    from pathlib import Path

    from scheimpflug.io.importer import read_image

    work = Path(work)
    count = [0]

    def figures(x):
        r = rig.replace(laser={"waist_um": math.exp(x[0]), "power_mw": math.exp(x[1])})
        out = work / f"r{count[0]:03d}"
        count[0] += 1
        render_poses(r, [camera_from_pattern], out, pattern, seed=seed, warn=lambda m: None)
        f = read_image(out / "frames" / "00000.png", "r")
        fwhm, peak = measure(f)
        return np.array([math.log(fwhm / target_fwhm_px), math.log(peak / target_peak_dn)])

    x = np.array([math.log(rig.laser.waist_um), math.log(rig.laser.power_mw)])
    g = figures(x)
    h = math.log(1.05)
    for _ in range(max_steps):
        if np.all(np.abs(g) <= math.log(1 + tol)):
            break
        jac = np.column_stack([(figures(x + h * e) - g) / h for e in np.eye(2)])
        try:
            step = -np.linalg.solve(jac, g)
        except np.linalg.LinAlgError:
            break
        step = np.clip(step, -1.0, 1.0)              # at most ×e per step
        x = x + step
        g = figures(x)
    ok = bool(np.all(np.abs(g) <= math.log(1 + tol)))
    return StripeFit(math.exp(x[0]), math.exp(x[1]), target_fwhm_px * math.exp(g[0]),
                     target_peak_dn * math.exp(g[1]), count[0], ok)
