"""Synthetic Scheimpflug frames from the closed forms of docs/explanation/design-notes.md §3 (test helper).

Independent of the geometry core and of the digital twin: a stripe is a
pixel-integrated Gaussian across columns, a plate edge a pixel-integrated,
Gaussian-blurred step along rows; photo-electrons get Poisson shot noise and
Gaussian read noise, then are quantised to 12 bit in a uint16 array.

Paper-rig nominal numbers (docs/explanation/design-notes.md §3): f = 55 mm, d = 150 mm,
tan φ = 0.2075, p = 5.86 µm → tan β = f / (d − f tan φ), F² = −f² / (p cos φ sin β),
C = f / sin β; u_h = 3196, v_h = 771, d0 = −466 mm.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from scipy.special import ndtr

F_MM, D_MM, TAN_PHI, PITCH_MM = 55.0, 150.0, 0.2075, 5.86e-3
TAN_BETA = F_MM / (D_MM - F_MM * TAN_PHI)
SIN_BETA = TAN_BETA / math.sqrt(1 + TAN_BETA ** 2)
COS_PHI = 1 / math.sqrt(1 + TAN_PHI ** 2)
F2_NOMINAL = -F_MM ** 2 / (PITCH_MM * COS_PHI * SIN_BETA)   # ≈ −1.4292e6 px·mm
C_NOMINAL = F_MM / SIN_BETA                                 # ≈ 149.10 mm


@dataclass(frozen=True)
class Geometry:
    """Ideal rig in the paper's calibration convention."""

    hinge_u_px: float = 3196.0
    hinge_v_px: float = 771.0
    F2_px_mm: float = F2_NOMINAL
    C_mm: float = C_NOMINAL
    d0_mm: float = -466.0
    columns: int = 1216
    rows: int = 1936

    def column(self, stage_mm):
        """Column of a point at stage coordinate s (Eq. 11 inverted) [px]."""
        return self.hinge_u_px + self.F2_px_mm / (np.asarray(stage_mm, float) - self.d0_mm)

    def row(self, u, h_mm):
        """Row of a point at height h seen at column u (Eq. 12 inverted) [px]."""
        return self.hinge_v_px + (np.asarray(u, float) - self.hinge_u_px) * np.asarray(h_mm, float) / self.C_mm


@dataclass(frozen=True)
class Camera:
    """Noise model: electrons → DN."""

    read_noise_e: float = 6.0
    gain_e_per_dn: float = 32000.0 / 4095.0
    offset_dn: float = 16.0
    bits: int = 12


@dataclass(frozen=True)
class PlateScene:
    """The calibration plate (89 mm high on a table 54 mm below the axis)."""

    bottom_mm: float = -54.0
    height_mm: float = 89.0
    sigma_px: float = 1.6            # stripe 1/e² half-width / 2 across columns [px]
    edge_blur_px: float = 0.8        # Gaussian blur of the plate edges along rows [px]
    total_e: float = 9000.0          # electrons per row in the stripe
    ambient_e: float = 40.0          # ambient electrons per pixel
    hot_pixels: int = 0
    extra: dict = field(default_factory=dict)


def _g(t):
    return t * ndtr(t) + np.exp(-0.5 * t * t) / math.sqrt(2 * math.pi)


def pixel_mean_step(centres, edge, blur):
    """Pixel average of Φ((y − edge)/blur) over [c − ½, c + ½] (blur > 0) [-]."""
    s = max(float(blur), 1e-6)
    c = np.asarray(centres, float)
    return s * (_g((c + 0.5 - edge) / s) - _g((c - 0.5 - edge) / s))


def stripe_profile(u_centre, sigma_px, columns):
    """(rows, columns) fraction of a unit-integral Gaussian falling in each pixel."""
    k = np.arange(columns, dtype=float)
    uc = np.asarray(u_centre, float)[..., None]
    return ndtr((k + 0.5 - uc) / sigma_px) - ndtr((k - 0.5 - uc) / sigma_px)


def to_dn(electrons, rng, cam: Camera):
    """Poisson shot + Gaussian read noise, quantised to ``cam.bits`` in uint16."""
    e = rng.poisson(np.clip(electrons, 0, None)).astype(float)
    e += rng.normal(0.0, cam.read_noise_e, e.shape)
    dn = np.rint(e / cam.gain_e_per_dn + cam.offset_dn)
    return np.clip(dn, 0, 2 ** cam.bits - 1).astype(np.uint16)


def plate_electrons(geo: Geometry, stage_mm: float, scene: PlateScene):
    """Mean electrons of the plate frame at stage ``stage_mm`` and its stripe column."""
    u = float(geo.column(stage_mm))
    v_top = float(geo.row(u, scene.bottom_mm + scene.height_mm))
    v_bot = float(geo.row(u, scene.bottom_mm))
    v = np.arange(geo.rows, dtype=float)
    cover = pixel_mean_step(v, v_top, scene.edge_blur_px) - pixel_mean_step(v, v_bot, scene.edge_blur_px)
    img = np.full((geo.rows, geo.columns), scene.ambient_e)
    lo, hi = max(int(u) - 25, 0), min(int(u) + 26, geo.columns)
    if hi > lo:
        k = np.arange(lo, hi, dtype=float)
        prof = ndtr((k + 0.5 - u) / scene.sigma_px) - ndtr((k - 0.5 - u) / scene.sigma_px)
        img[:, lo:hi] += scene.total_e * cover[:, None] * prof[None, :]
    return img, u, v_top, v_bot


def plate_frame(geo, stage_mm, scene, cam, rng):
    """A noisy uint16 plate frame and its truth (u, v_top, v_bot)."""
    img, u, v_top, v_bot = plate_electrons(geo, stage_mm, scene)
    frame = to_dn(img, rng, cam)
    for _ in range(scene.hot_pixels):
        frame[rng.integers(geo.rows), rng.integers(geo.columns)] = 2 ** cam.bits - 1
    return frame, (u, v_top, v_bot)


def rig_dict(geo: Geometry, cam: Camera | None = None) -> dict:
    """The rig tables of a manifest matching ``geo`` (paper values elsewhere)."""
    cam = cam or Camera()
    return {"lens": {"focal_length_mm": F_MM},
            "laser": {"scheimpflug_distance_mm": D_MM, "tan_phi": TAN_PHI},
            "sensor": {"pixel_pitch_um": PITCH_MM * 1e3, "columns": geo.columns,
                       "rows": geo.rows, "hinge_column": geo.hinge_u_px,
                       "axis_row": geo.hinge_v_px, "adc_bits": cam.bits,
                       "dark_offset_dn": cam.offset_dn},
            "stage": {"d0_mm": geo.d0_mm}}


def write_folder(path, frames, records, *, scenario="calibration", rig=None,
                 scenario_params=None) -> Path:
    """Write ``frames`` (list of 2-D arrays) as a frame folder (manifest + PNGs)."""
    path = Path(path)
    (path / "frames").mkdir(parents=True, exist_ok=True)
    entries = []
    for i, (frame, rec) in enumerate(zip(frames, records)):
        name = f"frames/{i:05d}.png"
        if not cv2.imwrite(str(path / name), frame):
            raise RuntimeError(f"cannot write {name}")
        entries.append({"file": name, "exposure_ms": 5.0, "seed": i, **rec})
    manifest = {"scenario": scenario, "scenario_params": scenario_params or {}, "frames": entries}
    if rig is not None:
        manifest["rig"] = rig
    (path / "manifest.json").write_text(json.dumps(manifest, indent=1))
    return path


def calibration_folder(path, geo=Geometry(), scene=PlateScene(), cam=Camera(), *,
                       stages=None, seed=0):
    """A whole calibration folder; returns (path, truths)."""
    stages = np.arange(0.0, 270.0, 10.0) if stages is None else np.asarray(stages, float)
    rng = np.random.default_rng(seed)
    frames, truths = [], []
    for s in stages:
        f, t = plate_frame(geo, s, scene, cam, rng)
        frames.append(f)
        truths.append(t)
    recs = [{"stage_mm": float(s)} for s in stages]
    write_folder(path, frames, recs, rig=rig_dict(geo, cam),
                 scenario_params={"plate_height_mm": scene.height_mm})
    return Path(path), truths


def grey_pngs(folder, names, shape=(20, 30), dtype=np.uint16) -> list[Path]:
    """Flat grey PNG files, one per name, each of its own level (100, 101, …: no two alike) [DN]."""
    paths = []
    for k, n in enumerate(names):
        p = Path(folder) / n
        assert cv2.imwrite(str(p), np.full(shape, 100 + k, dtype))
        paths.append(p)
    return paths
