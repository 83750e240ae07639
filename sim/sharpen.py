"""The camera's sharpening: an unsharp mask on its processed image, before the file is written.

Cheap cameras sharpen what they write (the Raspberry Pi camera's processor does, on the
luminance, after the tone curve).  The mask adds to every channel the luminance's detail
at the scale σ::

    c' = c + a · (Y − G_σ * Y),     Y = 0.299 R + 0.587 G + 0.114 B

c each channel's output level after the tone curve (before rounding to 8 bits), a =
``[chain] sharpen_amount``, G_σ the normalised Gaussian of standard deviation σ =
``[chain] sharpen_sigma_px`` in the frame's own pixels (the processor works on the frame it
writes), edges replicated.  Then rounding and clipping to [0, 255].  On a grey image (R = G
= B) this is the textbook unsharp mask of each channel.

Closed forms (the tests check them):

* a constant image is unchanged;
* across a Gaussian line of standard deviation w and peak A (no clipping),
  y'(x) = (1 + a)·A·exp(−x²/2w²) − a·A·(w/c)·exp(−x²/2c²), c² = w² + σ²: the peak grows by
  a·A·(1 − w/c) and beside the line the mask digs a moat below the background, deepest
  where y' is least — which the clip floors at 0 on a dark background (FabScan's walls);
* white noise of variance v becomes v·[(1 + a)² − 2a(1 + a)·g₀ + a²·Σg²], g₀ the kernel's
  centre weight and Σg² its squared weights' sum: for σ ≳ 1 px, g₀ ≈ 1/(2πσ²) and
  Σg² ≈ 1/(4πσ²).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

__all__ = ["LUMA_WEIGHTS", "unsharp_mask"]

#: Rec. 601 luma weights of R, G, B (what JPEG's YCbCr uses) [-].
LUMA_WEIGHTS = (0.299, 0.587, 0.114)


def unsharp_mask(levels, amount: float, sigma_px: float) -> np.ndarray:
    """The camera's sharpened image of its output levels (module docstring).

    Parameters
    ----------
    levels : (rows, columns, 3) or (rows, columns) float
        Output levels after the tone curve, not yet rounded [DN of 8 bits].
    amount : float
        a ≥ 0 [-]; 0 returns the levels unchanged (as float32).
    sigma_px : float
        σ > 0, the Gaussian's standard deviation in the frame's pixels [px].

    Returns
    -------
    ndarray of float32
        Same shape: c + a·(Y − G_σ * Y), not rounded nor clipped [DN].

    Raises
    ------
    ValueError
        For a negative amount, a σ that is not > 0, or levels that are not 2-D or (rows, columns, 3).
    """
    y = np.asarray(levels, dtype=np.float32)
    if not amount >= 0 or not sigma_px > 0:
        raise ValueError(f"unsharp mask: amount {amount!r} must be >= 0 and sigma {sigma_px!r} px > 0")
    if y.ndim not in (2, 3) or (y.ndim == 3 and y.shape[2] != 3):
        raise ValueError(f"unsharp mask: levels must be (rows, columns) or (rows, columns, 3), got {y.shape}")
    if amount == 0:
        return y
    luma = y if y.ndim == 2 else y @ np.asarray(LUMA_WEIGHTS, dtype=np.float32)
    detail = luma - ndimage.gaussian_filter(luma, float(sigma_px), mode="nearest")
    detail *= np.float32(amount)
    return y + (detail if y.ndim == 2 else detail[:, :, None])
