"""The colour filter array (Bayer mosaic) and the camera's demosaicing.

A Bayer sensor has one colour filter per pixel, repeating in 2 × 2 cells; the
pattern names the cell read row by row from the frame's top-left pixel (``RGGB``:
red at (0, 0), green at (0, 1) and (1, 0), blue at (1, 1)).  A pixel collects the
light of its own channel only: with the render's electrons counted at the
sensor's quantum efficiency QE, a pixel of channel c gets

    λ = (qe_laser,c · L + qe_other,c · F) / QE        [e⁻]

L and F the laser's and the other light's electrons on it (:func:`channel_factors`
gives the per-pixel factors).  Demosaicing interpolates the two missing channels
of every pixel: OpenCV's bilinear ``COLOR_Bayer*2RGB`` or edge-aware ``*_EA``
(:func:`demosaic`); OpenCV names a pattern by the second row's second and third
pixels, so RGGB is its ``BayerBG`` (:data:`OPENCV_CODES`, checked in the tests).
"""

from __future__ import annotations

import numpy as np

from scheimpflug.model.chain import BAYER_PATTERNS, DEMOSAIC_METHODS

__all__ = ["OPENCV_CODES", "channel_factors", "channel_map", "demosaic"]

#: Our pattern name → OpenCV's Bayer name (its convention is offset by one pixel diagonally).
OPENCV_CODES = {"RGGB": "BG", "BGGR": "RG", "GRBG": "GB", "GBRG": "GR"}
_CHANNEL = {"R": 0, "G": 1, "B": 2}


def _check_pattern(pattern: str) -> None:
    if pattern not in BAYER_PATTERNS:
        raise ValueError(f"unknown Bayer pattern {pattern!r} (one of {', '.join(BAYER_PATTERNS)})")


def channel_map(shape: tuple[int, int], pattern: str) -> np.ndarray:
    """The colour channel of every pixel.

    Parameters
    ----------
    shape : tuple of int
        (rows, columns) [px].
    pattern : {"RGGB", "BGGR", "GRBG", "GBRG"}
        The 2 × 2 cell from the top-left pixel.

    Returns
    -------
    (rows, columns) int8
        0 red, 1 green, 2 blue.

    Raises
    ------
    ValueError
        For an unknown pattern.
    """
    _check_pattern(pattern)
    cell = np.array([_CHANNEL[c] for c in pattern], dtype=np.int8).reshape(2, 2)
    rows, cols = shape
    return np.tile(cell, ((rows + 1) // 2, (cols + 1) // 2))[:rows, :cols]


def channel_factors(shape: tuple[int, int], pattern: str, qe_rgb, qe_sensor: float) -> np.ndarray:
    """Per-pixel factor from the render's electrons to the pixel's own channel's.

    Parameters
    ----------
    shape : tuple of int
        (rows, columns) [px].
    pattern : {"RGGB", "BGGR", "GRBG", "GBRG"}
        The 2 × 2 cell from the top-left pixel.
    qe_rgb : sequence of 3 float
        Quantum efficiency of the red, green and blue pixels for this light [e⁻/photon].
    qe_sensor : float
        The quantum efficiency the render counted electrons at [e⁻/photon], > 0.

    Returns
    -------
    (rows, columns) float32
        qe_c / qe_sensor of each pixel's channel c [-].

    Raises
    ------
    ValueError
        For an unknown pattern.
    """
    ratios = np.asarray(qe_rgb, dtype=np.float64) / float(qe_sensor)
    return ratios.astype(np.float32)[channel_map(shape, pattern)]


def demosaic(raw, pattern: str, method: str = "bilinear") -> np.ndarray:
    """The camera's RGB image of a mosaic.

    Parameters
    ----------
    raw : (rows, columns) uint16 or uint8
        Raw codes, one channel per pixel as ``pattern`` lays them out [DN].
    pattern : {"RGGB", "BGGR", "GRBG", "GBRG"}
        The 2 × 2 cell from the top-left pixel.
    method : {"bilinear", "edge_aware"}, default "bilinear"
        OpenCV's bilinear demosaicing or its edge-aware variant.

    Returns
    -------
    (rows, columns, 3) same dtype as ``raw``
        R, G, B per pixel [DN]; a uniform patch of each channel keeps its values exactly
        (away from the frame's one-pixel border).

    Raises
    ------
    ValueError
        For an unknown pattern or method, or ``raw`` not 2-D.
    """
    import cv2

    _check_pattern(pattern)
    if method not in DEMOSAIC_METHODS:
        raise ValueError(f"unknown demosaic method {method!r} (one of {', '.join(DEMOSAIC_METHODS)})")
    img = np.ascontiguousarray(raw)
    if img.ndim != 2:
        raise ValueError(f"raw must be a (rows, columns) array, got shape {img.shape}")
    code = getattr(cv2, f"COLOR_Bayer{OPENCV_CODES[pattern]}2RGB" + ("_EA" if method == "edge_aware" else ""))
    return cv2.cvtColor(img, code)
