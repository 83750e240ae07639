"""Shape checks at the door of the model's public geometry functions (as kornia's ``KORNIA_CHECK_SHAPE``).

A wrong shape raises :class:`ValueError` saying what was expected and what
came, instead of numpy silently broadcasting or slicing the wrong columns.
Private to :mod:`scheimpflug.model`; the public functions call these once.
"""

from __future__ import annotations

import numpy as np


def check_last_dim(name: str, array, n: int) -> np.ndarray:
    """``array`` as float64, checked to have shape ``(..., n)``.

    Parameters
    ----------
    name : str
        The argument's name, for the message (e.g. ``"points_mm"``).
    array : array_like
        The argument.
    n : int
        Required length of the last axis [-].

    Returns
    -------
    ndarray float64
        ``np.asarray(array, dtype=np.float64)``, shape ``(..., n)``.

    Raises
    ------
    ValueError
        If ``array`` has no axis or its last axis is not of length ``n``, e.g.
        "points_mm must have shape (..., 3), got (5, 2)".
    """
    a = np.asarray(array, dtype=np.float64)
    if a.ndim == 0 or a.shape[-1] != n:
        raise ValueError(f"{name} must have shape (..., {n}), got {a.shape}")
    return a


def check_broadcast(**arrays) -> list[np.ndarray]:
    """The keyword arrays as float64, checked to broadcast together.

    Parameters
    ----------
    **arrays : array_like
        The arguments by name, e.g. ``check_broadcast(u_px=u, v_px=v)``.

    Returns
    -------
    list of ndarray float64
        The arrays in keyword order, converted but not broadcast.

    Raises
    ------
    ValueError
        If the shapes do not broadcast, e.g.
        "u_px and v_px must broadcast together, got shapes (5,) and (3,)".
    """
    out = [np.asarray(a, dtype=np.float64) for a in arrays.values()]
    try:
        np.broadcast_shapes(*(a.shape for a in out))
    except ValueError:
        shapes = " and ".join(str(a.shape) for a in out)
        raise ValueError(f"{' and '.join(arrays)} must broadcast together, got shapes {shapes}") from None
    return out
