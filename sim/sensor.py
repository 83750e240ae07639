"""Image sensor: expected photo-electrons → digital numbers (DN), seeded.

The renderer (:mod:`sim.render`) returns, per pixel, the noise-free *expected*
number of photo-electrons collected during the exposure (laser + ambient,
pixel area, exposure time, quantum efficiency already included).  This module
turns it into the value a camera would deliver, in this order:

1. shot noise: ``n_e ~ Poisson(λ)`` [e⁻];
2. full-well saturation: ``n_e ← min(n_e, full_well_e)`` (charge that does not
   fit in the pixel is lost);
3. read noise: ``+ σ_read · N(0, 1)`` [e⁻] (Gaussian, added at read-out);
4. conversion gain and black level: ``DN = dark_offset_dn + n_e / g``;
5. ADC: round to the nearest integer and clip to ``[0, 2**adc_bits − 1]``.

The conversion gain ``g`` [e⁻/DN] is ``sensor.gain_e_per_dn``; when that is 0
the gain is chosen so that a full pixel reads exactly full scale:
``g = full_well_e / (2**adc_bits − 1 − dark_offset_dn)``.  No part of the
linear range is then lost to the ADC clip, and a saturated pixel reads
``2**adc_bits − 1`` (read noise can only push it down).

Storage: frames are ``uint16`` arrays holding the *raw ADC value* (0 …
2**adc_bits − 1); they are **not** left-shifted to 16-bit full scale.  The
frame folder's manifest records ``adc_bits`` so readers know full scale.

Statistics (unsaturated, away from the clip):
``E[DN] = dark_offset_dn + λ/g`` and
``Var[DN] = (λ + σ_read²)/g² + 1/12`` (the last term is the rounding of a
distribution wide compared to 1 DN).

Random numbers: a :class:`numpy.random.Generator` on PCG64 seeded by
``numpy.random.SeedSequence((seed, frame_index, 0x5E45))`` — the same
``(seed, frame_index)`` always gives bit-identical frames (with the same
numpy version), independent of how many frames were rendered before.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from scheimpflug.rig import Rig, Sensor

__all__ = [
    "SensorModel",
    "apply_sensor",
    "binned_rig",
    "conversion_gain_e_per_dn",
    "frame_rng",
    "full_scale_dn",
    "poisson_counts",
]

_STREAM_SENSOR = 0x5E45  # distinguishes the sensor-noise stream from other seeded streams


def frame_rng(seed: int, frame_index: int, stream: int = _STREAM_SENSOR) -> np.random.Generator:
    """The seeded generator of one frame: PCG64 from SeedSequence((seed, frame_index, stream))."""
    if seed < 0 or frame_index < 0:
        raise ValueError(f"seed and frame_index must be >= 0, got {seed}, {frame_index}")
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence((int(seed), int(frame_index),
                                                                       int(stream)))))


#: below this mean a count comes from inverting the Poisson CDF with one uniform (exact,
#: cost ∝ λ + 1); at and above it from PTRS transformed rejection (Hörmann 1993, the
#: algorithm of numpy's Generator.poisson for λ ≥ 10) with two uniforms.
_PTRS_LAMBDA = 10.0
_MAX_COUNT = 200                                   # inversion cap (P(X ≥ 200 | λ < 10) < 1e-150)
_INV_K = 1.0 / np.arange(1, _MAX_COUNT + 1, dtype=np.float64)   # 1/k: multiply, not divide


def _invert_poisson_numpy(lam, u, out, inv_k=_INV_K) -> None:
    """Reference of the kernel's inversion branch (same arithmetic), λ < _PTRS_LAMBDA."""
    lam = np.asarray(lam, dtype=np.float64)
    p = np.exp(-lam)
    cdf = p.copy()
    k = np.zeros(lam.shape, dtype=np.int64)
    active = u > cdf
    while active.any():
        idx = np.flatnonzero(active)
        p[idx] *= lam[idx] * inv_k[k[idx]]
        k[idx] += 1
        cdf[idx] += p[idx]
        active[idx] = (u[idx] > cdf[idx]) & (k[idx] < _MAX_COUNT)
    out[...] = k


@numba.njit(cache=True, nogil=True)
def _ptrs_once(lam, u, v):  # pragma: no cover - compiled
    """One PTRS trial (Hörmann 1993, as numpy's random_poisson_ptrs): count, or −1 if rejected."""
    b = 0.931 + 2.53 * math.sqrt(lam)
    a = -0.059 + 0.02483 * b
    vr = 0.9277 - 3.6224 / (b - 2.0)
    uu = u - 0.5
    us = 0.5 - abs(uu)
    k = math.floor((2.0 * a / us + b) * uu + lam + 0.43)
    if us >= 0.07 and v <= vr:                     # squeeze: accepted without logarithms
        return k
    if k < 0 or (us < 0.013 and v > us):
        return -1.0
    invalpha = 1.1239 + 1.1328 / (b - 3.4)
    if math.log(v) + math.log(invalpha) - math.log(a / (us * us) + b) \
            <= -lam + k * math.log(lam) - math.lgamma(k + 1.0):
        return k
    return -1.0


@numba.njit(parallel=True, cache=True, nogil=True)
def _inversion_kernel(lam, u, out, inv_k, ptrs_lambda):  # pragma: no cover - compiled
    """out[i] = min{k : F(k; λ_i) ≥ u[i]} for λ_i < ptrs_lambda, −1 (left to PTRS) otherwise."""
    for i in numba.prange(lam.shape[0]):
        mean = np.float64(lam[i])
        if mean >= ptrs_lambda:
            out[i] = -1.0
            continue
        p = math.exp(-mean)
        cdf = p
        k = 0
        while u[i] > cdf and k < _MAX_COUNT:
            p *= mean * inv_k[k]
            k += 1
            cdf += p
        out[i] = k


@numba.njit(parallel=True, cache=True, nogil=True)
def _ptrs_kernel(lam, uv, out):  # pragma: no cover - compiled
    """One PTRS trial per pixel with uniforms (uv[i], uv[n + i]); −1 = rejected."""
    n = lam.shape[0]
    for i in numba.prange(n):
        out[i] = _ptrs_once(np.float64(lam[i]), uv[i], uv[n + i])


@numba.njit(parallel=True, cache=True, nogil=True)
def _adc_kernel(charge, noise, full_well, read_noise, inv_gain, offset, full_scale, out):
    # pragma: no cover - compiled
    """DN = clip(rint(offset + (min(n_e, FW) + σ·N)/g), 0, full scale) → uint16."""
    for i in numba.prange(charge.shape[0]):
        e = min(charge[i], full_well) + read_noise * noise[i]
        dn = np.rint(e * inv_gain + offset)
        out[i] = np.uint16(min(max(dn, 0.0), full_scale))


def poisson_counts(lam, rng: np.random.Generator) -> np.ndarray:
    """Poisson-distributed counts with means ``lam`` (any shape), float32.

    Exact in distribution.  λ < 10: CDF inversion with one uniform per pixel
    (``rng.random(n)``, float64); λ ≥ 10: PTRS trials with two fresh uniforms each,
    repeated for the rejected pixels until all are accepted (≈ 80–90 % per round),
    which is PTRS exactly.  Pixels are independent and the kernels are parallel
    over them, so the result is deterministic whatever the thread count: same
    generator state → same counts.
    """
    flat = np.ascontiguousarray(lam, dtype=np.float32).reshape(-1)
    counts = np.empty(flat.size, dtype=np.float32)
    _inversion_kernel(flat, rng.random(flat.size), counts, _INV_K, _PTRS_LAMBDA)
    todo = np.flatnonzero(counts < 0)
    while todo.size:
        sub = np.ascontiguousarray(flat[todo])
        trial = np.empty(todo.size, dtype=np.float32)
        _ptrs_kernel(sub, rng.random(2 * todo.size), trial)
        counts[todo] = trial
        todo = todo[trial < 0]
    return counts.reshape(np.shape(lam))


def full_scale_dn(sensor: Sensor) -> int:
    """Largest ADC code, 2**adc_bits − 1 [DN]."""
    return (1 << sensor.adc_bits) - 1


def conversion_gain_e_per_dn(sensor: Sensor) -> float:
    """Conversion gain g [e⁻/DN]; gain_e_per_dn = 0 → full well + dark offset = full scale."""
    if sensor.gain_e_per_dn > 0:
        return float(sensor.gain_e_per_dn)
    return sensor.full_well_e / (full_scale_dn(sensor) - sensor.dark_offset_dn)


@dataclass(frozen=True)
class SensorModel:
    """Noise and ADC parameters of one sensor, taken from ``rig.sensor``.

    full_well_e : saturation charge [e⁻].
    read_noise_e : RMS read noise [e⁻].
    dark_offset_dn : black level [DN].
    gain_e_per_dn : conversion gain actually used (> 0) [e⁻/DN].
    adc_bits : ADC depth [bit].
    """

    full_well_e: float
    read_noise_e: float
    dark_offset_dn: float
    gain_e_per_dn: float
    adc_bits: int

    @classmethod
    def from_rig(cls, rig: Rig) -> "SensorModel":
        s = rig.sensor
        return cls(s.full_well_e, s.read_noise_e, s.dark_offset_dn,
                   conversion_gain_e_per_dn(s), s.adc_bits)

    @property
    def full_scale_dn(self) -> int:
        """Largest ADC code [DN]."""
        return (1 << self.adc_bits) - 1

    def expected_dn(self, electrons) -> np.ndarray:
        """Noise-free mean DN of expected electrons (no clipping, no rounding) [DN]."""
        return self.dark_offset_dn + np.asarray(electrons, dtype=np.float64) / self.gain_e_per_dn

    def variance_dn2(self, electrons) -> np.ndarray:
        """Var[DN] = (λ + σ_read²)/g² + 1/12 for unsaturated pixels [DN²]."""
        lam = np.asarray(electrons, dtype=np.float64)
        return (lam + self.read_noise_e**2) / self.gain_e_per_dn**2 + 1.0 / 12.0


def apply_sensor(electrons, model: SensorModel, rng: np.random.Generator) -> np.ndarray:
    """Turn expected electrons (rows, columns) into a raw ADC frame, (rows, columns) uint16.

    Parameters
    ----------
    electrons : (rows, columns) float
        Expected photo-electrons per pixel, ≥ 0 [e⁻]; NaN or negative values raise.
    model : SensorModel
    rng : numpy.random.Generator
        Use :func:`frame_rng` for reproducible frames.

    Returns
    -------
    (rows, columns) uint16
        Raw ADC codes in ``[0, 2**adc_bits − 1]`` [DN] (not shifted to 16 bit).
    """
    lam = np.asarray(electrons)
    if lam.ndim != 2:
        raise ValueError(f"electrons must be a (rows, columns) array, got shape {lam.shape}")
    if not np.all(lam >= 0):  # also catches NaN
        raise ValueError("electrons must be finite and >= 0 (expected photo-electrons per pixel)")
    charge = poisson_counts(lam, rng).reshape(-1)
    if model.read_noise_e > 0:
        noise = rng.standard_normal(charge.size, dtype=np.float32)
    else:
        noise = np.zeros(charge.size, dtype=np.float32)
    out = np.empty(charge.size, dtype=np.uint16)
    _adc_kernel(charge, noise, np.float32(model.full_well_e), np.float32(model.read_noise_e),
                np.float32(1.0 / model.gain_e_per_dn), np.float32(model.dark_offset_dn),
                np.float32(model.full_scale_dn), out)
    return out.reshape(lam.shape)


def binned_rig(rig: Rig, k: int) -> Rig:
    """The same rig read out with k × k binning (a reduced-resolution sensor, same geometry).

    A binned pixel j covers original pixels k·j … k·j + k − 1, so its centre is at
    original coordinate u = k·j + (k − 1)/2.  Hence: pitch × k; columns and rows
    // k (a remainder at the far edge is dropped); hinge_column, axis_row →
    (x − (k − 1)/2)/k; pixel offsets / k.  Sensor plane, hinge and sheet are
    unchanged, so F² [px·mm] scales by 1/k and C is unchanged.  Photometry:
    a binned pixel has k² times the area, so the exposure time is divided by k²
    — a binned pixel collects the charge an unbinned one would (the operator
    re-exposes), and frames stay as far from saturation as at full resolution;
    full well, read noise and ADC are those of the rig's sensor table.
    """
    if not isinstance(k, int) or isinstance(k, bool) or k < 1:
        raise ValueError(f"binning must be an integer >= 1, got {k!r}")
    if k == 1:
        return rig
    s = rig.sensor
    if s.columns < k or s.rows < k:
        raise ValueError(f"binning {k} leaves no pixel of a {s.columns} × {s.rows} sensor")
    c = (k - 1) / 2
    return rig.replace(sensor={
        "pixel_pitch_um": s.pixel_pitch_um * k, "columns": s.columns // k, "rows": s.rows // k,
        "hinge_column": (s.hinge_column - c) / k, "axis_row": (s.axis_row - c) / k,
        "offset_u_px": s.offset_u_px / k, "offset_v_px": s.offset_v_px / k,
        "exposure_ms": s.exposure_ms / (k * k)})
