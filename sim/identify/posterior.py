"""The posterior over the free parameters: surrogate likelihood and MCMC, or ABC on the runs.

Likelihood (surrogate).  A fitted figure j is compared on its scale
(:func:`sim.identify.figures.to_scale`): the instrument's value z_j against the
surrogate's mean μ_j(x) (:mod:`sim.identify.surrogate`) with the covariance

    Σ(x) = diag(σ_j²)  +  T R T  +  diag(s_j²(x))

— the stated measurement uncertainties σ_j (independent), the twin's own
randomness T = diag(τ_j) with the correlation R between figures of one
experiment (σ(C) and the endpoint R² both come from the plate's endpoints),
estimated from the design runs' standardised leave-one-out residuals and shrunk
by :data:`CORRELATION_SHRINK` toward the identity, and the surrogate's own
variance s_j²(x).  The instrument is one realisation of its noise, as each twin
run is one of the twin's.

MCMC.  Random-walk Metropolis in the unit cube of the priors
(:class:`sim.identify.spec.Parameter`), :data:`CHAINS` chains started at the
design runs of highest likelihood, the proposal adapted during the burn-in (scaled
to an acceptance of 0.2–0.4, then the chains' covariance × 2.38²/d) and fixed
after it; the split R̂ of every parameter is reported.  Deterministic for a seed.

Or (``sampler = "emcee"``, :data:`SAMPLERS`) emcee's affine-invariant ensemble sampler
(Goodman & Weare 2010; Foreman-Mackey et al. 2013) on the same log posterior:
:data:`EMCEE_WALKERS` walkers (at least 2d + 2) started around the same starting points,
:data:`EMCEE_BURN` steps dropped, :data:`EMCEE_KEEP` kept, every :data:`THIN` th; the split R̂ over
the walkers and emcee's integrated autocorrelation time are reported.  Deterministic for a seed.

ABC (the fallback when a surrogate's cross-validated error is not below the
measurement uncertainty it is used with, or ``method = "abc"``): likelihood-free,
the design runs themselves weighted by the prior and a Gaussian kernel of the
measurement uncertainties, ``w_i ∝ p(x_i) exp(−½ Σ_j ((z_j − z_ij)/σ_j)²)``; the
twin's noise is in the runs' values.  Its effective sample size is reported.

Summaries: posterior mean, standard deviation, 5 % and 95 % quantiles (the 90 %
interval), the correlation of the parameters' unit coordinates, and whether a
parameter is identifiable: its 90 % interval, in unit coordinates, narrower than
:data:`FLAT_WIDTH_RATIO` of its prior's — otherwise the figures leave it flat.
"""

from __future__ import annotations

import logging
import math

import numpy as np

__all__ = ["CHAINS", "CORRELATION_SHRINK", "EDGE_FRACTION", "FLAT_WIDTH_RATIO", "SAMPLERS", "Likelihood",
           "abc_weights", "noise_correlation", "predictive_interval", "resample", "run_emcee", "run_mcmc",
           "run_sampler", "summarise"]

#: Chains of the MCMC [-].
CHAINS = 16
#: Burn-in and kept steps per chain, and the thinning of the kept steps [-].
BURN_STEPS, KEEP_STEPS, THIN = 2000, 4000, 10
#: A parameter whose 90 % posterior interval is at least this fraction of its prior's 90 % interval
#: (both in the prior's unit coordinates) is reported as not identifiable (flat) [-].
FLAT_WIDTH_RATIO = 0.8
#: An identifiable parameter whose 90 % interval reaches within this fraction (unit coordinates) of a
#: prior bound is reported at that edge: the figures may ask for more than the prior allows [-].
EDGE_FRACTION = 0.02
#: The samplers :func:`run_sampler` knows.
SAMPLERS = ("hand", "emcee")
#: emcee: walkers (at least 2d + 2), burn-in steps dropped and steps kept (every THIN th) [-].
EMCEE_WALKERS, EMCEE_BURN, EMCEE_KEEP = 32, 1000, 3000
#: Weight of the identity in the estimated noise correlation between figures [-].
CORRELATION_SHRINK = 0.2


def noise_correlation(residuals: np.ndarray) -> np.ndarray:
    """Correlation of the twin's noise between figures, from standardised residuals, shrunk.

    Parameters
    ----------
    residuals : (n, F) ndarray
        Standardised leave-one-out residuals of n runs that measured all F figures.

    Returns
    -------
    (F, F) ndarray
        ``(1 − λ) R̂ + λ I`` with λ = :data:`CORRELATION_SHRINK` (the identity with fewer than
        5 runs or one figure).
    """
    n, f = residuals.shape
    if f < 2 or n < 5:
        return np.eye(f)
    r = np.corrcoef(residuals, rowvar=False)
    r = np.where(np.isfinite(r), r, 0.0)
    np.fill_diagonal(r, 1.0)
    return (1.0 - CORRELATION_SHRINK) * r + CORRELATION_SHRINK * np.eye(f)


class Likelihood:
    """The surrogate likelihood of the fitted figures (module docstring).

    Parameters
    ----------
    models : list of sim.identify.surrogate.GaussianProcess
        One surrogate per fitted figure.
    observed : (F,) array_like
        The instrument's values on the figures' scales.
    sigma : (F,) array_like
        Measurement uncertainties (1 σ) on the scales.
    correlation : (F, F) array_like
        Correlation of the twin's noise between the figures.
    """

    def __init__(self, models, observed, sigma, correlation) -> None:
        self.models = list(models)
        self.observed = np.asarray(observed, dtype=np.float64)
        tau = np.array([m.noise_sd for m in self.models])
        self.fixed = np.diag(np.asarray(sigma, dtype=np.float64) ** 2) + np.outer(tau, tau) * np.asarray(correlation)

    def __call__(self, x) -> np.ndarray:
        """Log likelihood at unit coordinates ``x``, up to a constant.

        Parameters
        ----------
        x : (m, d) array_like
            Unit coordinates [-].

        Returns
        -------
        (m,) ndarray
            ``−½ rᵀ Σ⁻¹ r − ½ log det Σ``.
        """
        x = np.atleast_2d(x)
        pred = [m.predict(x) for m in self.models]
        mu = np.stack([p[0] for p in pred], axis=1)
        var = np.stack([p[1] for p in pred], axis=1)
        cov = self.fixed[None, :, :] + np.eye(len(self.models))[None, :, :] * var[:, None, :]
        chol = np.linalg.cholesky(cov)
        r = (self.observed[None, :] - mu)[..., None]
        w = np.linalg.solve(chol, r)[..., 0]
        return -0.5 * np.sum(w * w, axis=1) - np.sum(np.log(np.diagonal(chol, axis1=1, axis2=2)), axis=1)


def _log_prior(parameters, x: np.ndarray) -> np.ndarray:
    return np.sum([p.log_prior(x[:, i]) for i, p in enumerate(parameters)], axis=0)


def _split_rhat(chains: np.ndarray) -> np.ndarray:
    """Split R̂ (Gelman et al., BDA3 §11.4) per parameter of (chains, steps, d) samples."""
    c, n, d = chains.shape
    half = n // 2
    s = np.concatenate([chains[:, :half], chains[:, half:2 * half]], axis=0)
    means, var = s.mean(axis=1), s.var(axis=1, ddof=1)
    b = half * means.var(axis=0, ddof=1)
    w = var.mean(axis=0)
    return np.sqrt(((half - 1) / half * w + b / half) / np.maximum(w, 1e-300))


def run_mcmc(log_likelihood, parameters, starts: np.ndarray, seed: int) -> dict:
    """Random-walk Metropolis on the unit cube of the priors (module docstring).

    Parameters
    ----------
    log_likelihood : callable
        ``(m, d) → (m,)`` log likelihood at unit coordinates.
    parameters : sequence of sim.identify.spec.Parameter
        The free parameters (their priors).
    starts : (CHAINS, d) ndarray
        Starting points [-].
    seed : int
        Seed of the chains [-].

    Returns
    -------
    dict
        ``samples`` ((CHAINS · KEEP_STEPS / THIN, d) unit coordinates), ``acceptance`` (kept
        steps' mean), ``rhat`` ((d,) split R̂), ``chains``, ``steps``.
    """
    rng = np.random.default_rng(np.random.SeedSequence((seed, 0x3C3C)))
    x = np.array(starts, dtype=np.float64)
    c, d = x.shape

    logp = _log_posterior(log_likelihood, parameters)
    lp = logp(x)
    step = np.full(c, 0.1)
    chol = np.eye(d)
    history, kept, kept_burn, accepted = [], [], [], 0
    for t in range(BURN_STEPS + KEEP_STEPS):
        prop = x + step[:, None] * (rng.standard_normal((c, d)) @ chol.T)
        lq = logp(prop)
        take = np.log(rng.random(c)) < lq - lp
        x, lp = np.where(take[:, None], prop, x), np.where(take, lq, lp)
        if t < BURN_STEPS:
            history.append(take)
            if (t + 1) % 100 == 0:
                rate = np.mean(history[-100:], axis=0)
                step *= np.where(rate < 0.2, 0.6, np.where(rate > 0.4, 1.5, 1.0))
            if t + 1 > BURN_STEPS // 2:
                kept_burn.append(x.copy())
            if t + 1 == BURN_STEPS:
                cov = np.cov(np.concatenate(kept_burn), rowvar=False).reshape(d, d) + 1e-10 * np.eye(d)
                chol = np.linalg.cholesky(cov) * 2.38 / math.sqrt(d)
                step = np.ones(c)
        else:
            accepted += int(take.sum())
            if (t - BURN_STEPS) % THIN == THIN - 1:
                kept.append(x.copy())
    chains = np.stack(kept, axis=1)
    return {"samples": chains.reshape(-1, d), "acceptance": accepted / (c * KEEP_STEPS),
            "rhat": _split_rhat(chains), "chains": c, "steps": KEEP_STEPS}


def _log_posterior(log_likelihood, parameters):
    def logp(u):
        lp = _log_prior(parameters, u)
        ok = np.isfinite(lp)
        out = np.full(len(u), -np.inf)
        if ok.any():
            out[ok] = lp[ok] + log_likelihood(u[ok])
        return out
    return logp


def run_emcee(log_likelihood, parameters, starts: np.ndarray, seed: int) -> dict:
    """The ensemble sampler of emcee on the unit cube of the priors (module docstring).

    Parameters
    ----------
    log_likelihood : callable
        ``(m, d) → (m,)`` log likelihood at unit coordinates.
    parameters : sequence of sim.identify.spec.Parameter
        The free parameters (their priors).
    starts : (k, d) ndarray
        Starting points [-]; the walkers start around them (cycled, 0.01 apart).
    seed : int
        Seed of the walkers' starts and moves [-].

    Returns
    -------
    dict
        As :func:`run_mcmc`'s — ``samples`` ((walkers · EMCEE_KEEP / THIN, d) unit coordinates),
        ``acceptance``, ``rhat`` (split R̂ over the walkers), ``chains`` (walkers), ``steps`` —
        and ``autocorr_steps`` ((d,) emcee's integrated autocorrelation time, steps).
    """
    import emcee

    starts = np.asarray(starts, dtype=np.float64)
    d = starts.shape[1]
    walkers = max(EMCEE_WALKERS, 2 * d + 2)
    rng = np.random.default_rng(np.random.SeedSequence((seed, 0xE3CE)))
    x0 = starts[np.arange(walkers) % len(starts)] + 0.01 * rng.standard_normal((walkers, d))
    x0 = np.clip(x0, 1e-6, 1 - 1e-6)
    sampler = emcee.EnsembleSampler(walkers, d, _log_posterior(log_likelihood, parameters), vectorize=True)
    sampler.random_state = np.random.RandomState(int(rng.integers(2 ** 31))).get_state()
    sampler.run_mcmc(x0, EMCEE_BURN + EMCEE_KEEP, progress=False)
    chains = np.swapaxes(sampler.get_chain(discard=EMCEE_BURN, thin=THIN), 0, 1)      # (walkers, kept, d)
    quiet = logging.getLogger("emcee.autocorr")
    level = quiet.level
    quiet.setLevel(logging.ERROR)       # a flat parameter's long τ is reported in the result, not logged
    try:
        tau = sampler.get_autocorr_time(discard=EMCEE_BURN, quiet=True)
    finally:
        quiet.setLevel(level)
    accepted = np.mean(np.diff(sampler.get_log_prob()[EMCEE_BURN - 1:], axis=0) != 0)
    return {"samples": chains.reshape(-1, d), "acceptance": float(accepted), "rhat": _split_rhat(chains),
            "chains": walkers, "steps": EMCEE_KEEP, "autocorr_steps": [float(t) for t in tau]}


def run_sampler(sampler: str, log_likelihood, parameters, starts: np.ndarray, seed: int) -> dict:
    """The named sampler (:data:`SAMPLERS`): :func:`run_mcmc` (``"hand"``) or :func:`run_emcee`.

    Parameters
    ----------
    sampler : {"hand", "emcee"}
        Which.
    log_likelihood : callable
        ``(m, d) → (m,)`` log likelihood at unit coordinates.
    parameters : sequence of sim.identify.spec.Parameter
        The free parameters (their priors).
    starts : (k, d) ndarray
        Starting points [-] (:data:`CHAINS` of them for ``"hand"``).
    seed : int
        Seed [-].

    Returns
    -------
    dict
        As :func:`run_mcmc`'s.
    """
    run = run_emcee if sampler == "emcee" else run_mcmc
    return run(log_likelihood, parameters, starts, seed)


def abc_weights(parameters, units: np.ndarray, values: np.ndarray, observed, sigma) -> np.ndarray:
    """ABC weights of the design runs (module docstring), normalised.

    Parameters
    ----------
    parameters : sequence of sim.identify.spec.Parameter
        The free parameters (their priors).
    units : (n, d) ndarray
        The runs' unit coordinates [-].
    values : (n, F) ndarray
        The runs' fitted figures on their scales (NaN where not measured: weight 0).
    observed, sigma : (F,) array_like
        The instrument's values and uncertainties on the scales.

    Returns
    -------
    (n,) ndarray
        Weights summing to 1 (all 0 when no run measured every figure).
    """
    r = (np.asarray(observed)[None, :] - values) / np.asarray(sigma)[None, :]
    logw = _log_prior(parameters, units) - 0.5 * np.sum(r * r, axis=1)
    logw = np.where(np.isfinite(logw), logw, -np.inf)
    if not np.isfinite(logw).any():
        return np.zeros(len(units))
    w = np.exp(logw - np.max(logw))
    return w / w.sum()


def resample(units: np.ndarray, weights: np.ndarray, n: int, seed: int) -> np.ndarray:
    """Systematic resampling of weighted points.

    Parameters
    ----------
    units : (m, d) ndarray
        Points [-].
    weights : (m,) ndarray
        Their weights (sum 1).
    n : int
        Samples wanted [-].
    seed : int
        Seed of the offset [-].

    Returns
    -------
    (n, d) ndarray
        The resampled points.
    """
    u0 = np.random.default_rng(np.random.SeedSequence((seed, 0xABC))).random()
    idx = np.searchsorted(np.cumsum(weights), (u0 + np.arange(n)) / n)
    return units[np.minimum(idx, len(units) - 1)]


def _quantile(v: np.ndarray, q, w: np.ndarray | None = None) -> np.ndarray:
    if w is None:
        return np.quantile(v, q)
    order = np.argsort(v)
    cw = np.cumsum(w[order]) - 0.5 * w[order]
    return np.interp(q, cw / w.sum(), v[order])


def _prior_width(p) -> float:
    """The prior's 90 % interval width in unit coordinates."""
    if p.prior != "normal":
        return 0.9
    q = (np.arange(20000) + 0.5) / 20000
    w = np.exp(p.log_prior(q))
    lo, hi = _quantile(q, [0.05, 0.95], w)
    return float(hi - lo)


def summarise(parameters, samples: np.ndarray, weights: np.ndarray | None = None) -> dict:
    """Posterior mean, σ, 90 % interval, identifiability and correlations (module docstring).

    Parameters
    ----------
    parameters : sequence of sim.identify.spec.Parameter
        The free parameters.
    samples : (m, d) ndarray
        Posterior samples in unit coordinates [-].
    weights : (m,) ndarray, optional
        Their weights (ABC); None = equal.

    Returns
    -------
    dict
        ``parameters``: per parameter ``key``, ``mean``, ``sd``, ``median``, ``lo90``, ``hi90``
        [key unit], ``width_ratio``, ``identifiable``, ``at_prior_edge`` (``"lower"``, ``"upper"``
        or None), ``prior``; ``correlation``: (d, d) list.
    """
    out = []
    w = None if weights is None else np.asarray(weights, dtype=np.float64)
    for i, p in enumerate(parameters):
        q = samples[:, i]
        v = p.value(q)
        mean = float(np.average(v, weights=w))
        sd = float(math.sqrt(np.average((v - mean) ** 2, weights=w)))
        lo, med, hi = (float(x) for x in _quantile(v, [0.05, 0.5, 0.95], w))
        qlo, qhi = _quantile(q, [0.05, 0.95], w)
        ratio = float((qhi - qlo) / _prior_width(p))
        ident = bool(ratio < FLAT_WIDTH_RATIO)
        edge = None if not ident else "lower" if qlo < EDGE_FRACTION else "upper" if qhi > 1 - EDGE_FRACTION else None
        out.append({"key": p.key, "mean": mean, "sd": sd, "median": med, "lo90": lo, "hi90": hi,
                    "width_ratio": ratio, "identifiable": ident, "at_prior_edge": edge,
                    "prior": {"lo": p.lo, "hi": p.hi, "form": p.describe()}})
    corr = np.ones((1, 1))
    if samples.shape[1] > 1:
        ww = np.full(len(samples), 1.0 / len(samples)) if w is None else w / w.sum()
        dev = samples - ww @ samples
        cov = (dev * ww[:, None]).T @ dev
        sd = np.sqrt(np.diag(cov))
        with np.errstate(invalid="ignore", divide="ignore"):      # a parameter without spread: no correlation
            corr = np.where(np.outer(sd, sd) > 0, cov / np.outer(sd, sd), np.nan)
        np.fill_diagonal(corr, 1.0)
    return {"parameters": out, "correlation": corr.tolist()}


def predictive_interval(values) -> dict:
    """The 90 % predictive interval of a figure from its values at posterior draws (order statistics).

    With n values sorted, ``[x_(k), x_(n+1−k)]`` with k = ⌊0.05 (n + 1)⌋ holds a new draw with
    probability (n + 1 − 2k)/(n + 1) ≥ 0.9 whatever the distribution (20 values: the smallest
    and the largest, 0.905).

    Parameters
    ----------
    values : sequence of float or None
        The figure at each posterior draw (None: not measured).

    Returns
    -------
    dict
        ``n`` (values measured), ``lo90``, ``hi90`` (None with fewer than 19 values),
        ``coverage``, ``median``.
    """
    v = np.sort(np.array([x for x in values if x is not None and math.isfinite(x)], dtype=np.float64))
    n = len(v)
    k = int(math.floor(0.05 * (n + 1)))
    if n == 0 or k < 1:
        return {"n": n, "lo90": None, "hi90": None, "coverage": None,
                "median": float(np.median(v)) if n else None}
    return {"n": n, "lo90": float(v[k - 1]), "hi90": float(v[n - k]), "coverage": (n + 1 - 2 * k) / (n + 1),
            "median": float(np.median(v))}
