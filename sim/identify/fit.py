"""From the design runs to the posterior: surrogates, their cross-validation, MCMC or ABC, the draws.

:func:`fit_posterior` is a pure function of the spec and the design runs'
records (deterministic for the spec's seed): one Gaussian process per fitted
figure (:mod:`sim.identify.surrogate`) over the runs that measured it, checked by
leave-one-out cross-validation against the figure's measurement uncertainty;
then the posterior (:mod:`sim.identify.posterior`) — MCMC on the surrogate
likelihood when every surrogate's own error is below its figure's uncertainty,
otherwise (or with ``method = "abc"``) ABC on the Latin hypercube's runs (drawn
from the prior, as ABC needs), the reason said — and the posterior draws at which
the held-out figures are rendered.  :func:`refinement_draws` places the optional
refinement runs (``[identify] refine``) where a first fit's tempered posterior is.
"""

from __future__ import annotations

import math

import numpy as np

from scheimpflug.errors import StudyError

from .figures import scale_sigma, to_scale
from .posterior import CHAINS, Likelihood, abc_weights, noise_correlation, resample, run_mcmc, summarise
from .surrogate import fit_gp

__all__ = ["MAX_SAMPLES_KEPT", "REFINE_TEMPER", "fit_posterior", "observed_on_scale", "refinement_draws"]

#: Posterior samples kept in ``posterior.json`` (for the plots) [-].
MAX_SAMPLES_KEPT = 4000
#: The first fit's likelihood is tempered by this factor (variances × it) to place the refinement runs [-].
REFINE_TEMPER = 4.0


def observed_on_scale(spec) -> tuple[np.ndarray, np.ndarray]:
    """The fitted figures' measured values and uncertainties on their scales.

    Parameters
    ----------
    spec : sim.identify.spec.IdentifySpec
        The spec.

    Returns
    -------
    observed, sigma : (F,) ndarray
        On each figure's scale (:func:`sim.identify.figures.to_scale`, :func:`scale_sigma`).
    """
    obs, sig = [], []
    for f in spec.fitted:
        scale = f.stat_scale
        obs.append(to_scale(scale, f.measured))
        sig.append(scale_sigma(scale, f.measured, f.absolute, f.relative))
    return np.array(obs), np.array(sig)


def _design_arrays(spec, records: list[dict]) -> tuple[np.ndarray, np.ndarray]:
    """(n, d) unit coordinates and (n, F) fitted figures on their scales (NaN: not measured)."""
    units = np.array([r["unit"] for r in records], dtype=np.float64).reshape(len(records), len(spec.parameters))
    values = np.full((len(records), len(spec.fitted)), np.nan)
    for i, r in enumerate(records):
        for j, f in enumerate(spec.fitted):
            v = r["figures"].get(f.name)
            if v is not None:
                values[i, j] = to_scale(f.stat_scale, v)
    return units, values


def _least_runs(d: int) -> int:
    return max(5, d + 2)


def _check_measured(spec, records, values: np.ndarray) -> None:
    for j, f in enumerate(spec.fitted):
        ok = np.isfinite(values[:, j])
        if ok.sum() < _least_runs(len(spec.parameters)):
            why = sorted({r["reasons"].get(f.name, "") for r, good in zip(records, ok) if not good} - {""})
            raise StudyError(f"only {int(ok.sum())} of {len(records)} design runs measured {f.name} "
                             f"({'; '.join(why[:2]) or 'no reason recorded'}): the twin cannot measure it over "
                             "most of the prior; narrow the ranges or change the experiment")


def _surrogates(spec, units, values, sigma) -> tuple[list, dict]:
    models, cv = [], {}
    for j, f in enumerate(spec.fitted):
        ok = np.isfinite(values[:, j])
        gp = fit_gp(units[ok], values[ok, j], seed=spec.seed)
        c = gp.cross_validation()
        c.update(scale=f.stat_scale, uncertainty=float(sigma[j]), ok=bool(c["error"] < sigma[j]),
                 length=[float(x) for x in gp.length])
        models.append(gp)
        cv[f.name] = c
    return models, cv


def _residual_correlation(models, values) -> np.ndarray:
    """Noise correlation from the standardised LOO residuals of the runs that measured every figure."""
    all_ok = np.all(np.isfinite(values), axis=1)
    cols = []
    for j, gp in enumerate(models):
        mean, var = gp.loo()
        full = np.full(len(values), np.nan)
        full[np.isfinite(values[:, j])] = (gp.z - mean) / np.sqrt(var)
        cols.append(full[all_ok])
    return noise_correlation(np.stack(cols, axis=1))


def _starts(spec, lik, units) -> np.ndarray:
    """CHAINS starting points: the design runs of highest posterior, nudged apart deterministically."""
    lp = lik(units) + np.sum([p.log_prior(units[:, i]) for i, p in enumerate(spec.parameters)], axis=0)
    order = np.argsort(-lp, kind="stable")
    rng = np.random.default_rng(np.random.SeedSequence((spec.seed, 0x57A7)))
    picks = units[order[np.arange(CHAINS) % len(order)]]
    return np.clip(picks + 0.01 * rng.standard_normal(picks.shape), 1e-6, 1 - 1e-6)


def _draws(spec, samples: np.ndarray, n: int, stream: int) -> np.ndarray:
    rng = np.random.default_rng(np.random.SeedSequence((spec.seed, stream)))
    return samples[np.sort(rng.choice(len(samples), n, replace=False))]


def _kept(samples: np.ndarray) -> np.ndarray:
    step = max(1, math.ceil(len(samples) / MAX_SAMPLES_KEPT))
    return samples[::step]


def fit_posterior(spec, records: list[dict], warn=None) -> dict:
    """The posterior of ``spec``'s free parameters from its design runs (module docstring).

    Parameters
    ----------
    spec : sim.identify.spec.IdentifySpec
        The spec.
    records : list of dict
        The design runs' records (:func:`sim.identify.runs.run_one`), in run order: the Latin
        hypercube's ``spec.runs`` first, then the refinement runs (if any).
    warn : callable, optional
        Receives the fallback's reason, one line.

    Returns
    -------
    dict
        ``method`` (``surrogate`` or ``abc``), ``fallback`` (why ABC, or ""), ``surrogate_cv_error``
        (per fitted figure: ``n``, ``rmse``, ``noise``, ``error``, ``z_rms``, ``uncertainty``, ``ok``,
        ``scale``, ``length``), ``noise_correlation``, ``mcmc`` or ``abc`` diagnostics, ``summary``
        (:func:`sim.identify.posterior.summarise`), ``samples`` (unit coordinates, at most
        :data:`MAX_SAMPLES_KEPT`), ``weights`` (ABC) and ``draws`` (the held-out runs' unit
        coordinates).

    Raises
    ------
    StudyError
        A fitted figure that too few design runs measured.
    """
    from threadpoolctl import threadpool_limits

    units, values = _design_arrays(spec, records)
    _check_measured(spec, records, values)
    with threadpool_limits(limits=1, user_api="blas"):     # small matrices: one thread is the fastest
        return _fit(spec, units, values, warn)


def refinement_draws(spec, records: list[dict]) -> list[list[float]]:
    """Where the refinement runs go: draws of a first fit's posterior, tempered :data:`REFINE_TEMPER` × wider.

    The Latin hypercube's runs give a first surrogate; its likelihood raised to the power
    1/:data:`REFINE_TEMPER` (each Gaussian's variance × that) is sampled by the MCMC, and
    ``spec.refine`` distinct samples become the next runs — so that the surrogate is trained where
    the posterior is, not only over the whole prior.  Used whatever the first surrogate's
    cross-validated error: it only places runs.

    Parameters
    ----------
    spec : sim.identify.spec.IdentifySpec
        The spec (``spec.refine`` > 0).
    records : list of dict
        The Latin hypercube's runs.

    Returns
    -------
    list of list of float
        ``spec.refine`` unit coordinates.

    Raises
    ------
    StudyError
        A fitted figure that too few runs measured.
    """
    from threadpoolctl import threadpool_limits

    units, values = _design_arrays(spec, records)
    _check_measured(spec, records, values)
    with threadpool_limits(limits=1, user_api="blas"):
        obs, sigma = observed_on_scale(spec)
        models, _ = _surrogates(spec, units, values, sigma)
        lik = Likelihood(models, obs, sigma, _residual_correlation(models, values))

        def tempered(u):
            return lik(u) / REFINE_TEMPER
        chain = run_mcmc(tempered, spec.parameters, _starts(spec, tempered, units), spec.seed + 1)
        return _draws(spec, chain["samples"], spec.refine, 0x4EF1).tolist()


def _fit(spec, units: np.ndarray, values: np.ndarray, warn) -> dict:
    obs, sigma = observed_on_scale(spec)
    models, cv = _surrogates(spec, units, values, sigma)
    out = {"surrogate_cv_error": cv, "fallback": "", "observed": obs.tolist(), "sigma": sigma.tolist()}
    bad = [f"{name} (error {c['error']:.3g} ≥ uncertainty {c['uncertainty']:.3g} on its {c['scale']} scale)"
           for name, c in cv.items() if not c["ok"]]
    if spec.method == "abc" or bad:
        if bad:
            out["fallback"] = ("the surrogate's cross-validated error is not below the measurement uncertainty "
                               f"for {', '.join(bad)}: ABC on the design runs instead")
            if warn:
                warn(out["fallback"])
        n = spec.runs      # ABC weighs runs drawn from the prior: the Latin hypercube's, not the refinement's
        return _abc(spec, units[:n], values[:n], obs, sigma, out)
    corr = _residual_correlation(models, values)
    lik = Likelihood(models, obs, sigma, corr)
    chain = run_mcmc(lik, spec.parameters, _starts(spec, lik, units), spec.seed)
    samples = chain["samples"]
    out.update(method="surrogate", noise_correlation=corr.tolist(), summary=summarise(spec.parameters, samples),
               mcmc={"chains": chain["chains"], "steps": chain["steps"], "acceptance": chain["acceptance"],
                     "rhat": [float(x) for x in chain["rhat"]]},
               samples=_kept(samples).tolist(), weights=None,
               draws=_draws(spec, samples, spec.posterior_draws, 0xD4A3).tolist())
    return out


def _abc(spec, units, values, obs, sigma, out: dict) -> dict:
    w = abc_weights(spec.parameters, units, values, obs, sigma)
    if not w.any():
        raise StudyError("ABC: no design run measured every fitted figure; narrow the ranges or change the "
                         "experiment")
    ess = float(1.0 / np.sum(w * w))
    out.update(method="abc", noise_correlation=None, summary=summarise(spec.parameters, units, w),
               abc={"runs": int(len(units)), "effective_sample_size": ess},
               samples=units.tolist(), weights=w.tolist(),
               draws=resample(units, w, spec.posterior_draws, spec.seed).tolist())
    return out
