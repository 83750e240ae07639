"""Veiling glare: the lens's point spread with a long tail, applied to the light on the sensor.

The point spread function is a core plus a long-tailed component::

    PSF = (1 − η)·δ + η·K,    K(r) = s / (2π (s² + r²)^(3/2))      [1/px²]

η = ``[chain] glare_fraction``, s = ``[chain] glare_scale_um`` / ``[sensor] pixel_pitch_um``, r the
distance from the image point [px].  The core δ is the image as rendered: the lens's own blur
(defocus, the pixel and aperture sampling of :mod:`sim.camera_pass`) is already in
it.  K is normalised (∫ K dA = 1) and is the solid-angle density, over 2π, of the
plane seen from a point at height s — so its integral over a pixel is exact in
closed form (:func:`tail_kernel`), and its line spread (the halo across a thin
line) is the Cauchy profile::

    LSF(x) = ∫ K dy = (s/π) / (s² + x²)       [1/px]

It falls as r⁻³ (r⁻² across a line): the glow beside a bright stripe reaches
many s.  The convolution (FFT, zero-padded: no wrap-around) keeps the offsets up to
a reach R = min(n − 1, max(⌈n/5⌉, ⌈20·s⌉)) along each axis of n pixels
(:func:`glare_reach`); beyond it K holds ≈ s/R of its energy (≤ 5 % of the
tail when R = 20·s), and that light is lost (:func:`tail_kernel` returns what is
kept).  Within the reach the halo is exact.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import scipy.fft

__all__ = ["apply_glare", "fft_length", "glare_reach", "line_spread", "tail_kernel"]


def line_spread(x_px, scale_px: float) -> np.ndarray:
    """The tail's line spread function: the halo across an infinitely thin line of unit power.

    Parameters
    ----------
    x_px : array_like
        Distance from the line [px].
    scale_px : float
        Scale s of the tail [px], > 0.

    Returns
    -------
    ndarray of float64
        (s/π) / (s² + x²) [1/px], same shape as ``x_px``.
    """
    x = np.asarray(x_px, dtype=np.float64)
    return (scale_px / np.pi) / (scale_px**2 + x**2)


def glare_reach(n: int, scale_px: float) -> int:
    """The largest offset the glare's convolution keeps along an axis (module docstring).

    Parameters
    ----------
    n : int
        Pixels along the axis, ≥ 1.
    scale_px : float
        Scale s of the tail [px], > 0.

    Returns
    -------
    int
        R = min(n − 1, max(⌈n/5⌉, ⌈20·s⌉)) [px].
    """
    return int(min(n - 1, max(math.ceil(n / 5), math.ceil(20.0 * scale_px))))


def fft_length(n: int, reach: int) -> int:
    """The FFT length of an axis of n pixels convolved with offsets up to a reach: the smallest 2^a·3^b ≥ n + reach.

    Parameters
    ----------
    n : int
        Pixels along the axis, ≥ 1.
    reach : int
        The largest offset kept, 0 … n − 1 [px].

    Returns
    -------
    int
        The length [px]: no offset within the reach wraps around.
    """
    want, best, p2 = n + reach, None, 1
    while best is None or p2 < best:
        p = p2
        while p < want:
            p *= 3
        best = p if best is None else min(best, p)
        p2 *= 2
    return best


def _corner(x: np.ndarray, y: np.ndarray, s: float) -> np.ndarray:
    """∫₀ˣ∫₀ʸ K dA: the solid angle of the rectangle seen from height s, over 2π."""
    return np.arctan2(x * y, s * np.sqrt(s * s + x * x + y * y)) / (2.0 * np.pi)


@functools.lru_cache(maxsize=4)
def tail_kernel(reach: tuple[int, int], scale_px: float) -> np.ndarray:
    """The tail K integrated exactly over each pixel, for offsets within a reach.

    Parameters
    ----------
    reach : tuple of int
        (Δrow, Δcolumn) kept: offsets −reach … +reach along each axis [px].
    scale_px : float
        Scale s of the tail [px], > 0.

    Returns
    -------
    (2·reach[0] + 1, 2·reach[1] + 1) float64
        ∫ K over each pixel [-], centred; sums to the energy the reach keeps
        (1 − the part beyond it).  Read-only, cached.
    """
    ry, rx = reach
    ey = np.arange(-ry, ry + 2, dtype=np.float64) - 0.5
    ex = np.arange(-rx, rx + 2, dtype=np.float64) - 0.5
    f = _corner(ex[None, :], ey[:, None], float(scale_px))
    k = f[1:, 1:] - f[:-1, 1:] - f[1:, :-1] + f[:-1, :-1]
    k.flags.writeable = False
    return k


@functools.lru_cache(maxsize=4)
def _kernel_spectrum(shape: tuple[int, int], scale_px: float) -> np.ndarray:
    """rfft2 of the tail kernel wrapped onto the FFT grid of frames of ``shape``."""
    reach = tuple(glare_reach(m, scale_px) for m in shape)
    n = tuple(fft_length(m, r) for m, r in zip(shape, reach))
    k = tail_kernel(reach, scale_px)
    grid = np.zeros(n, dtype=np.float32)
    iy = np.arange(-reach[0], reach[0] + 1) % n[0]
    ix = np.arange(-reach[1], reach[1] + 1) % n[1]
    grid[np.ix_(iy, ix)] = k
    spectrum = scipy.fft.rfft2(grid, workers=-1)
    spectrum.flags.writeable = False
    return spectrum


def apply_glare(image, fraction: float, scale_px: float) -> np.ndarray:
    """Light on the sensor after the lens's veiling glare (module docstring).

    Parameters
    ----------
    image : (rows, columns) float
        Light (or expected electrons) per pixel as imaged by the core, ≥ 0 [any unit].
    fraction : float
        η, the tail's share of the light [-], in [0, 1).
    scale_px : float
        s, the tail's scale [px], > 0.

    Returns
    -------
    (rows, columns) float32
        (1 − η)·image + η·(K ∗ image), same unit; ``image`` itself (as float32) when η = 0.

    Raises
    ------
    ValueError
        When ``image`` is not 2-D, ``fraction`` is outside [0, 1) or ``scale_px`` ≤ 0.
    """
    img = np.asarray(image, dtype=np.float32)
    if img.ndim != 2:
        raise ValueError(f"image must be a (rows, columns) array, got shape {img.shape}")
    if not (0.0 <= fraction < 1.0) or not scale_px > 0:
        raise ValueError(f"glare fraction must be in [0, 1) and scale > 0, got {fraction}, {scale_px}")
    if fraction == 0.0:
        return img
    n = tuple(fft_length(m, glare_reach(m, scale_px)) for m in img.shape)
    spread = scipy.fft.irfft2(scipy.fft.rfft2(img, s=n, workers=-1) * _kernel_spectrum(img.shape, float(scale_px)),
                              s=n, workers=-1)[:img.shape[0], :img.shape[1]]
    out = np.float32(1.0 - fraction) * img + np.float32(fraction) * spread
    return np.maximum(out, 0.0, out=out)       # FFT round-off: no negative light
