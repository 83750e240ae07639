"""JPEG: encoding a camera's 8-bit RGB frame, and a JPEG file's quality from its quantisation tables.

Encoding uses a real encoder (Pillow's libjpeg) at an IJG quality Q and a chroma
subsampling.  libjpeg (``jcparam.c``, ``jpeg_quality_scaling`` and
``jpeg_add_quant_table``) makes its tables from the standard ones of ITU-T T.81
Annex K (:data:`STD_LUMINANCE`, :data:`STD_CHROMINANCE`, natural order)::

    S(Q) = 5000 / Q  for Q < 50,   200 − 2·Q  otherwise
    T_i  = clip(⌊(B_i · S + 50) / 100⌋, 1, 255)            (baseline tables)

so a file's quality is the Q whose tables are the file's (:func:`estimate_quality`):
exact when both tables match, else the Q of the smallest summed difference,
reported as not exact (a camera with tables of its own).
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["STD_CHROMINANCE", "STD_LUMINANCE", "JpegQuality", "encode_jpeg", "encode_png8",
           "estimate_quality", "ijg_table", "jpeg_quality_of_file"]

#: ITU-T T.81 Table K.1, luminance, natural (row-major) order.
STD_LUMINANCE = np.array([
    16, 11, 10, 16, 24, 40, 51, 61, 12, 12, 14, 19, 26, 58, 60, 55,
    14, 13, 16, 24, 40, 57, 69, 56, 14, 17, 22, 29, 51, 87, 80, 62,
    18, 22, 37, 56, 68, 109, 103, 77, 24, 35, 55, 64, 81, 104, 113, 92,
    49, 64, 78, 87, 103, 121, 120, 101, 72, 92, 95, 98, 112, 100, 103, 99], dtype=np.int64)
#: ITU-T T.81 Table K.2, chrominance, natural (row-major) order.
STD_CHROMINANCE = np.array([
    17, 18, 24, 47, 99, 99, 99, 99, 18, 21, 26, 66, 99, 99, 99, 99,
    24, 26, 56, 99, 99, 99, 99, 99, 47, 66, 99, 99, 99, 99, 99, 99,
    *([99] * 32)], dtype=np.int64)

_SUBSAMPLING = {"4:4:4": 0, "4:2:2": 1, "4:2:0": 2}


def ijg_table(base, quality: int) -> np.ndarray:
    """The quantisation table libjpeg makes for an IJG quality (module docstring).

    Parameters
    ----------
    base : (64,) int
        The standard table (:data:`STD_LUMINANCE` or :data:`STD_CHROMINANCE`).
    quality : int
        Q, 1 … 100 [-].

    Returns
    -------
    (64,) int64
        clip(⌊(B·S(Q) + 50)/100⌋, 1, 255).

    Raises
    ------
    ValueError
        For Q outside 1 … 100.
    """
    if not 1 <= int(quality) <= 100:
        raise ValueError(f"JPEG quality must be 1 … 100, got {quality}")
    q = int(quality)
    scale = 5000 // q if q < 50 else 200 - 2 * q
    return np.clip((np.asarray(base, dtype=np.int64) * scale + 50) // 100, 1, 255)


@dataclass(frozen=True)
class JpegQuality:
    """A JPEG file's IJG quality as found from its quantisation tables.

    Parameters
    ----------
    quality : int
        Q whose libjpeg tables are nearest the file's [-].
    exact : bool
        True when every table of the file is libjpeg's for that Q.
    mismatch : int
        Σ |T_file − T_Q| over the compared tables (0 when exact) [-].
    """

    quality: int
    exact: bool
    mismatch: int


def estimate_quality(tables) -> JpegQuality:
    """The IJG quality of a JPEG's quantisation tables.

    Parameters
    ----------
    tables : mapping of int to (64,) int
        Table id → its 64 values in natural order (Pillow's ``Image.quantization``);
        table 0 is compared with the scaled luminance table, table 1 (if any) with the
        chrominance one.

    Returns
    -------
    JpegQuality
        The Q of the smallest summed absolute difference (the highest such Q on a tie).

    Raises
    ------
    ValueError
        When there is no table 0 or a table does not hold 64 values.
    """
    if 0 not in tables:
        raise ValueError("a JPEG needs a quantisation table 0 (luminance)")
    have = [(np.asarray(tables[k], dtype=np.int64), base) for k, base in ((0, STD_LUMINANCE), (1, STD_CHROMINANCE))
            if k in tables]
    if any(t.shape != (64,) for t, _ in have):
        raise ValueError("a quantisation table holds 64 values")
    costs = [sum(int(np.abs(t - ijg_table(base, q)).sum()) for t, base in have) for q in range(1, 101)]
    best = 100 - int(np.argmin(costs[::-1]))
    return JpegQuality(best, costs[best - 1] == 0, costs[best - 1])


def jpeg_quality_of_file(path) -> JpegQuality:
    """The IJG quality of a JPEG file (:func:`estimate_quality` on its tables).

    Parameters
    ----------
    path : str or Path
        The JPEG file.

    Returns
    -------
    JpegQuality
        Its quality.

    Raises
    ------
    ValueError
        When the file is not a JPEG.
    """
    from PIL import Image

    with Image.open(Path(path)) as im:
        if im.format != "JPEG":
            raise ValueError(f"{str(path)!r} is not a JPEG file ({im.format})")
        return estimate_quality(im.quantization)


def encode_jpeg(rgb, quality: int, subsampling: str = "4:2:0") -> bytes:
    """Encode an 8-bit RGB frame as a baseline JFIF JPEG (Pillow's libjpeg).

    Parameters
    ----------
    rgb : (rows, columns, 3) uint8
        The frame [DN].
    quality : int
        IJG quality, 1 … 100 [-].
    subsampling : {"4:4:4", "4:2:2", "4:2:0"}, default "4:2:0"
        Chroma subsampling.

    Returns
    -------
    bytes
        The file's content; its tables are :func:`ijg_table` of Q.

    Raises
    ------
    ValueError
        For a frame that is not (rows, columns, 3) uint8, a quality outside 1 … 100
        or an unknown subsampling.
    """
    from PIL import Image

    img = np.asarray(rgb)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"a JPEG frame is (rows, columns, 3) uint8, got {img.dtype} {img.shape}")
    if not 1 <= int(quality) <= 100 or subsampling not in _SUBSAMPLING:
        raise ValueError(f"JPEG quality 1 … 100 and subsampling in {list(_SUBSAMPLING)}, "
                         f"got {quality}, {subsampling!r}")
    out = io.BytesIO()
    Image.fromarray(img, "RGB").save(out, "JPEG", quality=int(quality), subsampling=_SUBSAMPLING[subsampling])
    return out.getvalue()


def encode_png8(rgb) -> bytes:
    """Encode an 8-bit RGB frame as PNG (OpenCV, zlib level 1).

    Parameters
    ----------
    rgb : (rows, columns, 3) uint8
        The frame [DN].

    Returns
    -------
    bytes
        The PNG file's content (8-bit RGB, lossless).

    Raises
    ------
    ValueError
        For a frame that is not (rows, columns, 3) uint8.
    """
    import cv2

    img = np.asarray(rgb)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"a PNG8 frame is (rows, columns, 3) uint8, got {img.dtype} {img.shape}")
    ok, data = cv2.imencode(".png", np.ascontiguousarray(img[..., ::-1]), [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise ValueError("OpenCV could not encode the frame as PNG")
    return data.tobytes()
