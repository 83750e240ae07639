"""Global sensitivity of a measurement error to the tolerances that cause it (Sobol, Morris, first order).

A tolerance study draws every toleranced quantity ``x_k`` from its
distribution, measures an error ``Y`` per draw and asks which ``x_k`` the
variance of ``Y`` comes from.  The draws are planned in the unit hypercube:
``q ∈ (0, 1)^d`` with independent uniform coordinates, mapped to the
tolerances by their inverse distribution functions (:func:`deviation_from_unit`),
so the index estimators see uniform inputs and the indices are those of the
real distributions (a Sobol index depends on the distribution of ``x_k``,
not on how it is parametrised).

Methods (SALib, Herman & Usher 2017):

``sobol``
    Saltelli's scheme on a scrambled Sobol sequence without second-order
    terms: ``N·(d + 2)`` draws for ``d`` tolerances, ``N`` a power of two.
    First-order index ``S1_k = V[E(Y|x_k)]/V(Y)`` (the share of the variance
    that ``x_k`` alone explains) and total index ``ST_k = E[V(Y|x_~k)]/V(Y)``
    (its share with all its interactions).  For an additive model
    ``S1 = ST`` and the first-order indices sum to 1.
``morris``
    Elementary effects on ``r`` one-at-a-time trajectories over a 4-level
    grid, ``r·(d + 1)`` draws: ``mu_star`` (the mean absolute effect of moving
    ``x_k`` over its whole range, in the units of ``Y``) ranks the
    tolerances cheaply; it is not a share of variance.

:func:`linear_shares` gives the first-order shares of a linearised model,
``S_k = (J_k σ_k)² / Σ_j (J_j σ_j)²`` — what the analytic propagation
(``J`` by finite differences) predicts for small tolerances.

References
----------
Saltelli, A. et al. (2010), Variance based sensitivity analysis of model
output, *Comput. Phys. Commun.* 181, 259–270.  Morris, M. D. (1991),
Factorial sampling plans for preliminary computational experiments,
*Technometrics* 33, 161–174.  Herman, J. and Usher, W. (2017), SALib: an
open-source Python library for sensitivity analysis, *JOSS* 2(9), 97.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import ndtri

__all__ = [
    "METHODS",
    "MORRIS_LEVELS",
    "NORMAL_MORRIS_SPAN",
    "SensitivityIndex",
    "deviation_from_unit",
    "draws_needed",
    "linear_shares",
    "morris_indices",
    "rank_indices",
    "sobol_indices",
    "unit_sample",
]

#: Sampling and analysis methods of a tolerance study.
METHODS = ("sobol", "morris")
#: Grid levels of the Morris trajectories [-].
MORRIS_LEVELS = 4
#: A normal tolerance's Morris grid spans ±this many σ (the grid needs finite ends) [-].
NORMAL_MORRIS_SPAN = 3.0
_Q_CLIP = 1e-9   # unit coordinates are kept in [clip, 1 − clip] before a normal inverse [-]


@dataclass(frozen=True)
class SensitivityIndex:
    """The sensitivity of one output to one tolerance.

    Parameters
    ----------
    key : str
        The toleranced rig key (``"sensor.roll_deg"``).
    first_order : float or None
        Sobol first-order index S1 [-] (None for Morris screening).
    total : float or None
        Sobol total index ST [-] (None for Morris screening).
    first_order_conf, total_conf : float or None
        Half-widths of their 95 % bootstrap intervals [-].
    mu_star, sigma : float or None
        Morris: mean absolute elementary effect and its spread over the
        trajectories, in the output's unit (None for Sobol).
    """

    key: str
    first_order: float | None = None
    total: float | None = None
    first_order_conf: float | None = None
    total_conf: float | None = None
    mu_star: float | None = None
    sigma: float | None = None

    def to_json(self) -> dict:
        """JSON-ready dict (None stays null; docs/reference/interface.md fields ``key``, ``first_order``, ``total``).

        Returns
        -------
        dict
            Every field.
        """
        return {k: (None if v is None else (v if isinstance(v, str) else float(v)))
                for k, v in self.__dict__.items()}

    @property
    def importance(self) -> float:
        """What the ranking sorts by: ST, else S1, else mu_star (NaN sorts last) [-]."""
        for v in (self.total, self.first_order, self.mu_star):
            if v is not None and math.isfinite(v):
                return float(v)
        return -math.inf


def _problem(d: int) -> dict:
    return {"num_vars": d, "names": [f"q{k}" for k in range(d)], "bounds": [[0.0, 1.0]] * d}


def draws_needed(method: str, n_keys: int, base: int = 2) -> int:
    """Draws a method needs for ``base`` Sobol base samples or Morris trajectories.

    Parameters
    ----------
    method : {"sobol", "morris"}
        The method.
    n_keys : int
        Number of tolerances d (≥ 1).
    base : int
        N (Sobol, a power of two) or r (Morris) [-].

    Returns
    -------
    int
        ``base·(d + 2)`` (Sobol) or ``base·(d + 1)`` (Morris).

    Raises
    ------
    ValueError
        For an unknown method.
    """
    if method == "sobol":
        return base * (n_keys + 2)
    if method == "morris":
        return base * (n_keys + 1)
    raise ValueError(f"unknown sensitivity method {method!r} (known: {', '.join(METHODS)})")


def unit_sample(method: str, n_keys: int, draws: int, seed: int) -> np.ndarray:
    """The study's draws in the unit hypercube, seeded (same seed, same draws).

    Parameters
    ----------
    method : {"sobol", "morris"}
        ``sobol``: Saltelli's scheme on a scrambled Sobol sequence, N = the largest
        power of two with N·(d + 2) ≤ ``draws``; ``morris``: r = ``draws`` // (d + 1)
        trajectories on a 4-level grid.
    n_keys : int
        Number of tolerances d (≥ 1).
    draws : int
        Draws allowed (the sample uses at most this many).
    seed : int
        Seed of the sequence's scrambling / the trajectories (≥ 0).

    Returns
    -------
    (n, d) float64
        Unit coordinates, row k = draw k; n ≤ ``draws``.

    Raises
    ------
    ValueError
        An unknown method, ``n_keys`` < 1, or fewer draws than the method's minimum
        (2 base samples), the message naming the minimum.
    """
    if n_keys < 1:
        raise ValueError("a tolerance study needs at least one tolerance")
    minimum = draws_needed(method, n_keys, 2)
    if draws < minimum:
        raise ValueError(f"draws = {draws}: method {method!r} with {n_keys} tolerance(s) needs at least "
                         f"{minimum} draws (2 base samples of {minimum // 2})")
    if method == "sobol":
        from SALib.sample import sobol as sobol_sample

        n = 1 << int(math.floor(math.log2(draws // (n_keys + 2))))
        return np.asarray(sobol_sample.sample(_problem(n_keys), n, calc_second_order=False,
                                              scramble=True, seed=int(seed)), dtype=np.float64)
    from SALib.sample import morris as morris_sample

    r = draws // (n_keys + 1)
    return np.asarray(morris_sample.sample(_problem(n_keys), r, num_levels=MORRIS_LEVELS,
                                           seed=int(seed)), dtype=np.float64)


def deviation_from_unit(q, kind: str, width: float, method: str = "sobol"):
    """The tolerance's deviation for unit coordinates q (its inverse distribution function).

    Parameters
    ----------
    q : array_like float
        Unit coordinates in [0, 1].
    kind : {"uniform", "normal"}
        Distribution of the deviation.
    width : float
        Half-width a of the uniform distribution on [−a, a], or σ of the normal (> 0),
        in the key's unit.
    method : {"sobol", "morris"}
        For ``morris`` the grid's ends 0 and 1 map to ±``NORMAL_MORRIS_SPAN``·σ for a normal
        tolerance (an inverse normal of 0 or 1 is infinite).

    Returns
    -------
    ndarray float64
        Deviations, shape of ``q``, in the key's unit.

    Raises
    ------
    ValueError
        For an unknown ``kind``.
    """
    q = np.asarray(q, dtype=np.float64)
    if kind == "uniform":
        return width * (2.0 * q - 1.0)
    if kind != "normal":
        raise ValueError(f"unknown tolerance distribution {kind!r} (uniform, normal)")
    if method == "morris":
        return width * NORMAL_MORRIS_SPAN * (2.0 * q - 1.0)
    return width * ndtri(np.clip(q, _Q_CLIP, 1.0 - _Q_CLIP))


def sobol_indices(keys, y, seed: int = 0) -> list[SensitivityIndex]:
    """First-order and total Sobol indices from the outputs of a :func:`unit_sample` ("sobol").

    Parameters
    ----------
    keys : sequence of str
        The d tolerance names, in the sample's column order.
    y : (N·(d + 2),) float
        The output of every draw, in draw order (all finite).
    seed : int
        Seed of the bootstrap of the confidence intervals.

    Returns
    -------
    list of SensitivityIndex
        One per key, in key order (``first_order``, ``total`` and their 95 % intervals).

    Raises
    ------
    ValueError
        A length that is not a multiple of d + 2, or a non-finite output.
    """
    from SALib.analyze import sobol

    y = np.asarray(y, dtype=np.float64)
    d = len(keys)
    if y.ndim != 1 or y.size == 0 or y.size % (d + 2):
        raise ValueError(f"Sobol analysis of {d} keys needs N·{d + 2} outputs, got shape {y.shape}")
    if not np.all(np.isfinite(y)):
        raise ValueError(f"Sobol analysis needs every draw's output: {int((~np.isfinite(y)).sum())} are missing")
    if np.ptp(y) == 0:
        return [SensitivityIndex(k, 0.0, 0.0, 0.0, 0.0) for k in keys]
    r = sobol.analyze(_problem(d), y, calc_second_order=False, seed=int(seed))
    return [SensitivityIndex(k, float(r["S1"][i]), float(r["ST"][i]), float(r["S1_conf"][i]),
                             float(r["ST_conf"][i])) for i, k in enumerate(keys)]


def morris_indices(keys, q, y, seed: int = 0) -> list[SensitivityIndex]:
    """Morris screening (mu_star, sigma) from the outputs of a :func:`unit_sample` ("morris").

    Parameters
    ----------
    keys : sequence of str
        The d tolerance names.
    q : (r·(d + 1), d) float
        The unit sample.
    y : (r·(d + 1),) float
        The output of every draw (all finite).
    seed : int
        Seed of the bootstrap.

    Returns
    -------
    list of SensitivityIndex
        One per key: ``mu_star`` and ``sigma`` per unit of the whole tolerance range, in the
        output's unit; ``first_order`` and ``total`` None.

    Raises
    ------
    ValueError
        Shapes that do not match or a non-finite output.
    """
    from SALib.analyze import morris

    q = np.asarray(q, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if q.ndim != 2 or q.shape != (y.size, len(keys)):
        raise ValueError(f"Morris analysis: sample {q.shape} and outputs {y.shape} do not match {len(keys)} keys")
    if not np.all(np.isfinite(y)):
        raise ValueError(f"Morris analysis needs every draw's output: {int((~np.isfinite(y)).sum())} are missing")
    r = morris.analyze(_problem(len(keys)), q, y, num_levels=MORRIS_LEVELS, seed=int(seed))
    return [SensitivityIndex(k, mu_star=float(r["mu_star"][i]), sigma=float(r["sigma"][i]))
            for i, k in enumerate(keys)]


def linear_shares(jacobian, sigmas) -> np.ndarray:
    """First-order variance shares of a linearised model, ``(J_k σ_k)² / Σ_j (J_j σ_j)²``.

    Parameters
    ----------
    jacobian : (d,) float
        ∂Y/∂x_k [output unit per key unit].
    sigmas : (d,) float
        Standard deviations of the x_k [key unit].

    Returns
    -------
    (d,) float64
        Shares summing to 1 (all 0 when no key moves Y).

    Raises
    ------
    ValueError
        If the shapes differ.
    """
    j = np.asarray(jacobian, dtype=np.float64)
    s = np.asarray(sigmas, dtype=np.float64)
    if j.shape != s.shape:
        raise ValueError(f"jacobian {j.shape} and sigmas {s.shape} must have one entry per key")
    v = (j * s) ** 2
    total = v.sum()
    return v / total if total > 0 else np.zeros_like(v)


def rank_indices(indices) -> list[SensitivityIndex]:
    """The indices sorted most important first (ST, else S1, else mu_star; ties by key).

    Parameters
    ----------
    indices : iterable of SensitivityIndex
        One per key.

    Returns
    -------
    list of SensitivityIndex
        Sorted.
    """
    return sorted(indices, key=lambda s: (-s.importance, s.key))
