"""FabScanPi's own point formulae, re-implemented from its source for the tests (not imported from it).

FabScanPi-Server (commit afdcbb9, ``FSImageProcessor``): the frame turned by ``cv2.transpose``
and ``cv2.flip(…, 1)``, a pixel's ray ``((u − cx)/fx, (v − cy)/fy, 1)`` met with the laser
plane ``n·X = d`` (no undistortion), the platform ``Rᵀ(X − t)``, turned by ``R_z(angle)``.
"""

import numpy as np

from scheimpflug.fitting import fit_rigid


def fabscan_points(lines, across, angles_deg, cfg) -> np.ndarray:
    """FabScan's points of stripe samples of frames stored unturned, stripe along the rows.

    ``lines`` are the stored frames' columns, ``across`` their rows; ``angles_deg`` this
    pipeline's θ per frame (FabScan's angle is −θ).
    """
    c = cfg["calibration"]
    k = np.array(c["camera_matrix"])
    n, d = np.array(c["laser_planes"][0]["normal"]), c["laser_planes"][0]["distance"]
    r, t = np.array(c["platform_rotation"]), np.array(c["platform_translation"])
    width = cfg["camera"]["resolution"]["height"]                  # the turned frame's width
    out = []
    for ln, ac, a in zip(lines, across, angles_deg):
        u2, v2 = (width - 1) - np.asarray(ac, float), np.asarray(ln, float)
        x = np.stack([(u2 - k[0, 2]) / k[0, 0], (v2 - k[1, 2]) / k[1, 1], np.ones_like(u2)])
        xp = r.T @ (d / (n @ x) * x - t[:, None])
        th = np.radians(-a)
        out.append(np.stack([np.cos(th) * xp[0] - np.sin(th) * xp[1], np.sin(th) * xp[0] + np.cos(th) * xp[1],
                             xp[2]], 1))
    return np.concatenate(out)


def rigid_rms(a, b, mirror=False) -> float:
    """RMS of b − (R·a + t) after the best proper rigid motion (or, ``mirror``, the best improper one) [mm]."""
    return fit_rigid(a, b, mirror=mirror)[2]
