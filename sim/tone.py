"""Tone: raw ADC codes → the camera's 8-bit output codes (black level, tone curve, pedestal).

A camera's processing subtracts its sensor's black level b [raw DN], scales the
linear range to [0, 1], x = clip((D − b)/(D_max − b), 0, 1) with D_max = 2^bits − 1,
applies its tone curve T and writes 8 bits with a pedestal p [DN]::

    out = round(p + (255 − p)·T(x))

T is one of (x in [0, 1]):

- ``gamma``: x^(1/γ) (γ = 1: linear);
- ``srgb`` (IEC 61966-2-1): 12.92·x for x ≤ 0.0031308, else 1.055·x^(1/2.4) − 0.055;
- ``bt709`` (ITU-R BT.709-6, the camera's OETF): 4.5·x for x < 0.018, else 1.099·x^0.45 − 0.099;
- ``table``: straight lines through given points (x_k, y_k) (``[chain] tone_table``).

The gain before the ADC (``[chain] analogue_gain``) is the sensor's
(:mod:`sim.chain`); here everything is a lookup table over raw codes
(:func:`output_lut`), so demosaiced raw codes map to output codes in one take.
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["output_levels", "output_lut", "tone_curve"]


def tone_curve(x, curve: str, gamma: float = 1.0, table: tuple = ()) -> np.ndarray:
    """The tone curve T of a linear signal (module docstring).

    Parameters
    ----------
    x : array_like
        Linear signal, clipped to [0, 1] [-].
    curve : {"gamma", "srgb", "bt709", "table"}
        The transfer function.
    gamma : float, default 1.0
        γ of ``"gamma"`` (> 0) [-]; ignored otherwise.
    table : tuple of (xs, ys), default ()
        The points of ``"table"``: xs increasing from 0 to 1, ys in [0, 1] [-].

    Returns
    -------
    ndarray of float64
        T(x) in [0, 1] [-], same shape as ``x``.

    Raises
    ------
    ValueError
        For an unknown curve, γ ≤ 0, or ``"table"`` without points.
    """
    v = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    if curve == "gamma":
        if not gamma > 0:
            raise ValueError(f"gamma must be > 0, got {gamma}")
        return v ** (1.0 / gamma)
    if curve == "srgb":
        return np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055)
    if curve == "bt709":
        return np.where(v < 0.018, 4.5 * v, 1.099 * v**0.45 - 0.099)
    if curve == "table":
        if len(table) != 2 or len(table[0]) < 2:
            raise ValueError("the table tone curve needs its points (xs, ys)")
        return np.interp(v, table[0], table[1])
    raise ValueError(f"unknown tone curve {curve!r} (gamma, srgb, bt709, table)")


@functools.lru_cache(maxsize=8)
def output_levels(adc_bits: int, black_dn: float, pedestal_dn: float, curve: str, gamma: float,
                  table: tuple = ()) -> np.ndarray:
    """The output level of every raw code before rounding to 8 bits (what a camera sharpens).

    Parameters
    ----------
    adc_bits, black_dn, pedestal_dn, curve, gamma, table
        As :func:`output_lut`.

    Returns
    -------
    (2**adc_bits,) float64
        p + (255 − p)·T(clip((D − b)/(2^adc_bits − 1 − b), 0, 1)) for D = 0 … 2^adc_bits − 1
        (read-only, cached) [DN].
    """
    full = (1 << adc_bits) - 1
    x = (np.arange(full + 1, dtype=np.float64) - black_dn) / (full - black_dn)
    levels = pedestal_dn + (255.0 - pedestal_dn) * tone_curve(x, curve, gamma, table)
    levels.flags.writeable = False
    return levels


@functools.lru_cache(maxsize=8)
def output_lut(adc_bits: int, black_dn: float, pedestal_dn: float, curve: str, gamma: float,
               table: tuple = ()) -> np.ndarray:
    """The 8-bit output code of every raw code.

    Parameters
    ----------
    adc_bits : int
        Raw depth [bit], 1 … 16.
    black_dn : float
        b, the sensor's black level the camera subtracts [raw DN], < 2^adc_bits − 1.
    pedestal_dn : float
        p, the output code of black [DN], in [0, 255).
    curve : {"gamma", "srgb", "bt709", "table"}
        The tone curve.
    gamma : float
        γ of ``"gamma"`` [-].
    table : tuple of (xs, ys), default ()
        The points of ``"table"`` [-].

    Returns
    -------
    (2**adc_bits,) uint8
        round(p + (255 − p)·T(clip((D − b)/(2^adc_bits − 1 − b), 0, 1))) for D = 0 … 2^adc_bits − 1
        (read-only, cached).
    """
    lut = np.rint(output_levels(adc_bits, black_dn, pedestal_dn, curve, gamma, table)).astype(np.uint8)
    lut.flags.writeable = False
    return lut
