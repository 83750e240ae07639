"""A Gaussian-process surrogate of one figure over the free parameters, with its own cross-validation.

The twin's figure at unit coordinates x ∈ [0, 1]^d (:class:`sim.identify.spec.Parameter`)
is modelled on its statistical scale (:func:`sim.identify.figures.to_scale`) as

    z(x) = f(x) + ε,   f ~ GP(0, k),   ε ~ N(0, τ²)

after standardising z.  The kernel is an anisotropic Matérn 5/2 plus a linear
term, ``k(x, x') = s² m(r) + b² (1 + (x − ½)·(x' − ½))`` with
``r² = Σ_i ((x_i − x'_i)/ℓ_i)²`` and ``m(r) = (1 + √5 r + 5r²/3) e^(−√5 r)`` — the
linear term lets a figure that changes steadily over the prior be followed
without short length scales (a Bayesian linear mean, integrated out).  The
white noise τ² is the twin's own randomness: runs at one x with other seeds
scatter by τ.  Hyperparameters (ℓ, s², b², τ²) maximise the marginal likelihood
(L-BFGS-B on their logarithms from fixed and seeded starts; deterministic).

Cross-validation is leave-one-out in closed form (Rasmussen & Williams 2006,
§5.4.2): with ``K_y = K + τ² I``, the prediction of run i from the others is
``z_i − [K_y⁻¹ z]_i / [K_y⁻¹]_ii`` with variance ``1 / [K_y⁻¹]_ii``.  The RMS of
those residuals is the error of predicting one new run; it contains the twin's
noise τ, so the surrogate's own error (of the figure's mean) is
``√max(rmse² − τ², 0)``.  Pure numpy/scipy; no state.

Two fits of that model (:data:`SURROGATES`): ``"hand"`` (:func:`fit_gp`, the kernel above,
this module's own marginal-likelihood optimiser) and ``"sklearn"`` (:func:`fit_gp_sklearn`,
scikit-learn's ``GaussianProcessRegressor`` with ``ConstantKernel × Matern(ν = 5/2, ARD) +
WhiteKernel`` — no linear term — and its own L-BFGS-B restarts).  Both return a surrogate with
the same methods (:meth:`GaussianProcess.predict`, :meth:`~GaussianProcess.loo`,
:meth:`~GaussianProcess.cross_validation`, :attr:`~GaussianProcess.noise_sd`), so the posterior
and the cross-validation are computed alike whichever fitted it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_factor, cho_solve, solve_triangular
from scipy.optimize import minimize

__all__ = ["SURROGATES", "GaussianProcess", "LibraryGP", "fit_gp", "fit_gp_sklearn", "fit_surrogate",
           "matern52"]

_SQRT5 = math.sqrt(5.0)
#: Bounds of the hyperparameters on the standardised scale: length scales over the unit cube,
#: Matérn and linear variances, noise variance.
_BOUNDS = {"length": (0.03, 30.0), "signal": (1e-4, 1e2), "linear": (1e-6, 1e2), "noise": (1e-8, 10.0)}
_JITTER = 1e-10
#: The surrogate fits :func:`fit_surrogate` knows.
SURROGATES = ("hand", "sklearn")
#: Optimiser starts of the scikit-learn fit: its initial kernel and this many random restarts, as
#: many starts as :func:`fit_gp`'s [-].
SKLEARN_RESTARTS = 7


def matern52(xa: np.ndarray, xb: np.ndarray, length: np.ndarray) -> np.ndarray:
    """Matérn 5/2 correlation between two sets of points.

    Parameters
    ----------
    xa : (n, d) ndarray
        Points [-].
    xb : (m, d) ndarray
        Points [-].
    length : (d,) ndarray
        Length scales [-].

    Returns
    -------
    (n, m) ndarray
        ``(1 + √5 r + 5 r²/3) exp(−√5 r)``, r the scaled distance.
    """
    diff = (xa[:, None, :] - xb[None, :, :]) / length
    r = np.sqrt(np.maximum(np.sum(diff * diff, axis=-1), 0.0))
    return (1.0 + _SQRT5 * r + (5.0 / 3.0) * r * r) * np.exp(-_SQRT5 * r)


def _kernel(xa, xb, length, signal, linear):
    return signal * matern52(xa, xb, length) + linear * (1.0 + (xa - 0.5) @ (xb - 0.5).T)


class _Surrogate:
    """What every fitted surrogate offers: prediction, closed-form leave-one-out, cross-validation.

    A subclass holds ``x``, ``z``, ``z_mean``, ``z_scale``, ``noise``, ``chol``, ``alpha`` and
    defines :meth:`_cross` (the signal kernel between new points and the runs) and
    :meth:`_prior_var` (its value at a new point with itself), both standardised.
    """

    @property
    def noise_sd(self) -> float:
        """The twin's noise τ on the figure's scale."""
        return math.sqrt(self.noise) * self.z_scale

    def predict(self, xs) -> tuple[np.ndarray, np.ndarray]:
        """The figure's mean and the surrogate's variance of it at ``xs``.

        Parameters
        ----------
        xs : (m, d) array_like
            Unit coordinates [-].

        Returns
        -------
        mean : (m,) ndarray
            Predicted mean on the figure's scale.
        var : (m,) ndarray
            Variance of that mean (the surrogate's, without the noise τ²) on the scale.
        """
        xs = np.atleast_2d(np.asarray(xs, dtype=np.float64))
        ks = self._cross(xs)
        mean = ks @ self.alpha
        v = solve_triangular(self.chol, ks.T, lower=True)
        var = np.maximum(self._prior_var(xs) - np.sum(v * v, axis=0), 0.0)
        return self.z_mean + self.z_scale * mean, var * self.z_scale ** 2

    def loo(self) -> tuple[np.ndarray, np.ndarray]:
        """Leave-one-out predictions of the training runs (closed form, module docstring).

        Returns
        -------
        mean : (n,) ndarray
            Run i predicted from the others, on the figure's scale.
        var : (n,) ndarray
            Its predictive variance, noise included.
        """
        inv = cho_solve((self.chol, True), np.eye(len(self.z)))
        d = np.diag(inv)
        zs = (self.z - self.z_mean) / self.z_scale
        return self.z_mean + self.z_scale * (zs - self.alpha / d), self.z_scale ** 2 / d

    def cross_validation(self) -> dict:
        """The surrogate's leave-one-out figures (module docstring).

        Returns
        -------
        dict
            ``n``, ``rmse`` (of predicting one new run), ``noise`` (τ), ``error``
            (√max(rmse² − τ², 0): the surrogate's own error of the mean), ``z_rms`` (RMS of the
            standardised residuals; ≈ 1 for honest predictive variances), all on the scale.
        """
        mean, var = self.loo()
        res = self.z - mean
        rmse = float(np.sqrt(np.mean(res * res)))
        return {"n": int(len(self.z)), "rmse": rmse, "noise": self.noise_sd,
                "error": math.sqrt(max(rmse * rmse - self.noise_sd ** 2, 0.0)),
                "z_rms": float(np.sqrt(np.mean(res * res / var)))}


@dataclass(frozen=True)
class GaussianProcess(_Surrogate):
    """A Gaussian process of one figure fitted by :func:`fit_gp` (module docstring).

    Parameters
    ----------
    x : (n, d) ndarray
        Training inputs (unit coordinates) [-].
    z : (n,) ndarray
        Training values on the figure's scale.
    z_mean, z_scale : float
        The standardisation: ``(z − z_mean) / z_scale``.
    length : (d,) ndarray
        Length scales [-].
    signal, linear, noise : float
        Matérn variance s², linear variance b², noise variance τ² (standardised).
    chol : (n, n) ndarray
        Lower Cholesky factor of ``K + τ² I``.
    alpha : (n,) ndarray
        ``(K + τ² I)⁻¹ z_std``.
    """

    x: np.ndarray
    z: np.ndarray
    z_mean: float
    z_scale: float
    length: np.ndarray
    signal: float
    linear: float
    noise: float
    chol: np.ndarray
    alpha: np.ndarray

    def _cross(self, xs: np.ndarray) -> np.ndarray:
        return _kernel(xs, self.x, self.length, self.signal, self.linear)

    def _prior_var(self, xs: np.ndarray) -> np.ndarray:
        return self.signal + self.linear * (1.0 + np.sum((xs - 0.5) ** 2, axis=1))


@dataclass(frozen=True)
class LibraryGP(_Surrogate):
    """A Gaussian process of one figure fitted by scikit-learn (:func:`fit_gp_sklearn`).

    Parameters
    ----------
    x : (n, d) ndarray
        Training inputs (unit coordinates) [-].
    z : (n,) ndarray
        Training values on the figure's scale.
    z_mean, z_scale : float
        The standardisation: ``(z − z_mean) / z_scale``.
    length : (d,) ndarray
        Matérn length scales [-].
    signal, noise : float
        Constant (Matérn variance) s² and white-noise variance τ² (standardised).
    chol : (n, n) ndarray
        Lower Cholesky factor of ``K + τ² I`` (scikit-learn's ``L_``).
    alpha : (n,) ndarray
        ``(K + τ² I)⁻¹ z_std`` (scikit-learn's ``alpha_``).
    """

    x: np.ndarray
    z: np.ndarray
    z_mean: float
    z_scale: float
    length: np.ndarray
    signal: float
    noise: float
    chol: np.ndarray
    alpha: np.ndarray

    def _cross(self, xs: np.ndarray) -> np.ndarray:
        return self.signal * matern52(xs, self.x, self.length)

    def _prior_var(self, xs: np.ndarray) -> np.ndarray:
        return np.full(len(xs), self.signal)


def _unpack(theta: np.ndarray, d: int):
    e = np.exp(theta)
    return e[:d], e[d], e[d + 1], e[d + 2]


def _nll(theta: np.ndarray, x: np.ndarray, zs: np.ndarray) -> tuple[float, np.ndarray]:
    """Negative log marginal likelihood and its gradient in the log hyperparameters."""
    d = x.shape[1]
    length, signal, linear, noise = _unpack(theta, d)
    diff2 = ((x[:, None, :] - x[None, :, :]) / length) ** 2
    r = np.sqrt(np.sum(diff2, axis=-1))
    e = np.exp(-_SQRT5 * r)
    m = (1.0 + _SQRT5 * r + (5.0 / 3.0) * r * r) * e
    lin = 1.0 + (x - 0.5) @ (x - 0.5).T
    k = signal * m + linear * lin + (noise + _JITTER) * np.eye(len(zs))
    try:
        c, low = cho_factor(k, lower=True, check_finite=False)
    except np.linalg.LinAlgError:
        return 1e25, np.zeros_like(theta)
    alpha = cho_solve((c, low), zs, check_finite=False)
    nll = float(0.5 * zs @ alpha + np.sum(np.log(np.diag(c))) + 0.5 * len(zs) * math.log(2 * math.pi))
    w = cho_solve((c, low), np.eye(len(zs)), check_finite=False) - np.outer(alpha, alpha)
    dm = (5.0 / 3.0) * (1.0 + _SQRT5 * r) * e          # ∂m/∂log ℓ_i = dm · (Δ_i/ℓ_i)²
    grad = np.empty_like(theta)
    for i in range(d):
        grad[i] = 0.5 * np.sum(w * signal * dm * diff2[:, :, i])
    grad[d] = 0.5 * np.sum(w * signal * m)
    grad[d + 1] = 0.5 * np.sum(w * linear * lin)
    grad[d + 2] = 0.5 * np.trace(w) * noise
    return nll, grad


def _starts(d: int, rng: np.random.Generator) -> list[np.ndarray]:
    fixed = [(0.3, 1.0, 0.1, 0.1), (1.0, 0.5, 1.0, 0.01), (3.0, 0.1, 1.0, 0.3), (0.15, 1.0, 0.01, 0.5)]
    out = [np.log([ell] * d + [s, b, t]) for ell, s, b, t in fixed]
    lo, hi = _log_bounds(d)
    out += [lo + rng.random(d + 3) * (hi - lo) for _ in range(4)]
    return out


def _log_bounds(d: int) -> tuple[np.ndarray, np.ndarray]:
    b = [_BOUNDS["length"]] * d + [_BOUNDS["signal"], _BOUNDS["linear"], _BOUNDS["noise"]]
    arr = np.log(np.array(b, dtype=np.float64))
    return arr[:, 0], arr[:, 1]


def fit_gp(x, z, seed: int = 0) -> GaussianProcess:
    """Fit a Gaussian process to runs ``(x, z)`` by maximum marginal likelihood (module docstring).

    Parameters
    ----------
    x : (n, d) array_like
        Unit coordinates of the runs [-].
    z : (n,) array_like
        The figure on its scale, one value per run.
    seed : int
        Seed of the random optimiser starts (the result is deterministic for it).

    Returns
    -------
    GaussianProcess
        The fitted surrogate.

    Raises
    ------
    ValueError
        Fewer than 3 runs, shapes that do not match, or non-finite values.
    """
    x, z, mean, scale, zs = _standardised(x, z)
    d = x.shape[1]
    lo, hi = _log_bounds(d)
    best = None
    for t0 in _starts(d, np.random.default_rng(seed)):
        res = minimize(_nll, np.clip(t0, lo, hi), args=(x, zs), method="L-BFGS-B", jac=True,
                       bounds=list(zip(lo, hi)))
        if best is None or res.fun < best.fun:
            best = res
    length, signal, linear, noise = _unpack(best.x, d)
    k = _kernel(x, x, length, signal, linear) + (noise + _JITTER) * np.eye(len(zs))
    chol = np.linalg.cholesky(k)
    alpha = cho_solve((chol, True), zs)
    return GaussianProcess(x, z, mean, scale, length, float(signal), float(linear), float(noise + _JITTER),
                           chol, alpha)


def _standardised(x, z):
    x = np.atleast_2d(np.asarray(x, dtype=np.float64))
    z = np.asarray(z, dtype=np.float64)
    if x.ndim != 2 or z.shape != (x.shape[0],) or x.shape[0] < 3:
        raise ValueError(f"need (n, d) inputs and (n,) values with n >= 3, got {x.shape} and {z.shape}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(z))):
        raise ValueError("the runs' coordinates and values must be finite")
    mean, scale = float(np.mean(z)), float(np.std(z))
    scale = scale if scale > 0 else 1.0
    return x, z, mean, scale, (z - mean) / scale


def fit_gp_sklearn(x, z, seed: int = 0) -> LibraryGP:
    """Fit the figure with scikit-learn's ``GaussianProcessRegressor`` (module docstring).

    ``ConstantKernel(s²) × Matern(ℓ, ν = 5/2) + WhiteKernel(τ²)`` on the standardised values, the
    same bounds as :func:`fit_gp`'s (:data:`_BOUNDS`), :data:`SKLEARN_RESTARTS` random restarts of
    scikit-learn's L-BFGS-B seeded by ``seed`` (deterministic for it).

    Parameters
    ----------
    x : (n, d) array_like
        Unit coordinates of the runs [-].
    z : (n,) array_like
        The figure on its scale, one value per run.
    seed : int
        Seed of the restarts.

    Returns
    -------
    LibraryGP
        The fitted surrogate.

    Raises
    ------
    ValueError
        Fewer than 3 runs, shapes that do not match, or non-finite values.
    """
    import warnings

    from sklearn.exceptions import ConvergenceWarning
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel

    x, z, mean, scale, zs = _standardised(x, z)
    d = x.shape[1]
    kernel = (ConstantKernel(1.0, _BOUNDS["signal"]) * Matern(np.full(d, 0.3), _BOUNDS["length"], nu=2.5)
              + WhiteKernel(0.1, _BOUNDS["noise"]))
    gpr = GaussianProcessRegressor(kernel, alpha=_JITTER, n_restarts_optimizer=SKLEARN_RESTARTS,
                                   normalize_y=False, random_state=seed)
    with warnings.catch_warnings():      # a bound reached is a fit, not a fault: the cross-validation judges it
        warnings.simplefilter("ignore", ConvergenceWarning)
        gpr.fit(x, zs)
    k = gpr.kernel_
    signal, length, noise = float(k.k1.k1.constant_value), np.atleast_1d(k.k1.k2.length_scale), float(k.k2.noise_level)
    return LibraryGP(x, z, mean, scale, np.broadcast_to(length, (d,)).astype(np.float64), signal,
                     noise + _JITTER, np.asarray(gpr.L_), np.asarray(gpr.alpha_))


def fit_surrogate(x, z, seed: int = 0, surrogate: str = "hand"):
    """Fit one figure's surrogate with the named fit (:data:`SURROGATES`).

    Parameters
    ----------
    x : (n, d) array_like
        Unit coordinates of the runs [-].
    z : (n,) array_like
        The figure on its scale.
    seed : int
        Seed of the optimiser's starts.
    surrogate : {"hand", "sklearn"}
        :func:`fit_gp` or :func:`fit_gp_sklearn`.

    Returns
    -------
    GaussianProcess or LibraryGP
        The fitted surrogate.
    """
    return fit_gp_sklearn(x, z, seed) if surrogate == "sklearn" else fit_gp(x, z, seed)
