"""Blooming: charge above a pixel's full well spilling along its column.

The rule, for each column on its own (rows i = 0 … n − 1, full well W [e⁻], spill
fraction f = ``[chain] bloom_spill_fraction``):

1. every pixel keeps min(q_i, W); of its excess e_i = max(q_i − W, 0) the share
   f spills, half toward row 0 and half toward row n − 1; the rest, (1 − f)·e_i,
   is drained (lost);
2. upward pass (i = n − 1 … 0): a carry c arriving at pixel i from below fills it
   up to W; what does not fit, plus the pixel's own upward half f·e_i/2, goes on
   to pixel i − 1; the carry leaving row 0 is lost off the sensor;
3. downward pass (i = 0 … n − 1): the same with the downward halves, into the
   room the upward pass left.

So charge is conserved: Σ q_out = Σ min(q_i, W) + f·Σ e_i − (carries lost at the
two ends).  An isolated saturated pixel with charge Q over a column of uniform
charge b < W fills L = ⌈f (Q − W) / (2 (W − b))⌉ pixels on each side (the last
one partly).  With f = 0 it is the full-well clip of :mod:`sim.sensor`.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["bloom_columns", "spill_length_px"]


@numba.njit(parallel=True, cache=True, nogil=True)
def _bloom_kernel(q, full_well, spill):  # pragma: no cover - compiled
    rows, cols = q.shape
    for j in numba.prange(cols):
        half = np.empty(rows, dtype=np.float64)
        for i in range(rows):
            e = max(np.float64(q[i, j]) - full_well, 0.0)
            half[i] = 0.5 * spill * e
            if e > 0.0:
                q[i, j] = full_well
        carry = 0.0
        for i in range(rows - 1, -1, -1):           # upward: toward row 0
            room = full_well - q[i, j]
            take = min(carry, room)
            q[i, j] += take
            carry = carry - take + half[i]
        carry = 0.0
        for i in range(rows):                        # downward: toward the last row
            room = full_well - q[i, j]
            take = min(carry, room)
            q[i, j] += take
            carry = carry - take + half[i]


def bloom_columns(charge, full_well_e: float, spill_fraction: float) -> np.ndarray:
    """Collected charge after blooming along columns (module docstring).

    Parameters
    ----------
    charge : (rows, columns) float
        Charge collected per pixel, before any full-well limit [e⁻], ≥ 0.
    full_well_e : float
        W, the pixel's capacity [e⁻], > 0.
    spill_fraction : float
        f, the share of the excess that spills [-], in [0, 1].

    Returns
    -------
    (rows, columns) float
        Charge per pixel, every value ≤ W [e⁻] (a new array; float64 when charge spilled, else
        the input's float type).

    Raises
    ------
    ValueError
        When ``charge`` is not 2-D, ``full_well_e`` ≤ 0 or ``spill_fraction`` is outside [0, 1].
    """
    q = np.asarray(charge)
    if q.ndim != 2:
        raise ValueError(f"charge must be a (rows, columns) array, got shape {q.shape}")
    if not full_well_e > 0 or not 0.0 <= spill_fraction <= 1.0:
        raise ValueError(f"need full_well_e > 0 and spill_fraction in [0, 1], got {full_well_e}, {spill_fraction}")
    if spill_fraction == 0.0 or not (q > full_well_e).any():
        return np.minimum(q, np.float32(full_well_e) if q.dtype == np.float32 else full_well_e)
    out = q.astype(np.float64)
    _bloom_kernel(out, float(full_well_e), float(spill_fraction))
    return out


def spill_length_px(excess_e: float, full_well_e: float, background_e: float, spill_fraction: float) -> int:
    """Pixels filled on each side of one saturated pixel in a uniform column (closed form).

    Parameters
    ----------
    excess_e : float
        Q − W, the saturated pixel's charge above the full well [e⁻].
    full_well_e : float
        W [e⁻].
    background_e : float
        b, the charge of the column's other pixels, < W [e⁻].
    spill_fraction : float
        f [-].

    Returns
    -------
    int
        L = ⌈f·(Q − W) / (2·(W − b))⌉ [px]: the pixels that receive spilled charge on each side.
    """
    return int(np.ceil(spill_fraction * excess_e / (2.0 * (full_well_e - background_e))))
