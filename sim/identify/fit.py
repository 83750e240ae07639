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

The inference backend (:class:`Inference`, :func:`parse_inference`): which fit of the
surrogates (``"hand"``, :func:`sim.identify.surrogate.fit_gp`, or ``"sklearn"``, scikit-learn's
``GaussianProcessRegressor``) and which sampler (``"hand"``, the random-walk Metropolis
:func:`sim.identify.posterior.run_mcmc`, or ``"emcee"``, emcee's ensemble sampler) — the
``backend`` argument, else the spec's ``inference`` attribute when it has one, else
:data:`DEFAULT_INFERENCE`.  Every backend gives the same outputs (summary, samples,
diagnostics); the one used is recorded as ``inference``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scheimpflug.errors import StudyError

from .figures import scale_sigma, to_scale
from .posterior import CHAINS, SAMPLERS, Likelihood, abc_weights, noise_correlation, resample, run_sampler, summarise
from .surrogate import SURROGATES, fit_surrogate

__all__ = ["DEFAULT_INFERENCE", "MAX_SAMPLES_KEPT", "REFINE_TEMPER", "RHAT_LIMIT", "Inference", "fit_posterior",
           "observed_on_scale", "parse_inference", "refinement_draws"]

#: Posterior samples kept in ``posterior.json`` (for the plots) [-].
MAX_SAMPLES_KEPT = 4000
#: The first fit's likelihood is tempered by this factor (variances × it) to place the refinement runs [-].
REFINE_TEMPER = 4.0
#: A sampler whose largest split R̂ exceeds this has not converged: its intervals are not the posterior's, and
#: the fit says so (``mcmc.converged``, a warning) [-].
RHAT_LIMIT = 1.1


@dataclass(frozen=True)
class Inference:
    """The inference backend: the surrogates' fit and the sampler (module docstring).

    Parameters
    ----------
    surrogate : {"hand", "sklearn"}
        :data:`sim.identify.surrogate.SURROGATES`.
    sampler : {"hand", "emcee"}
        :data:`sim.identify.posterior.SAMPLERS`.
    """

    surrogate: str = "hand"
    sampler: str = "hand"

    def __str__(self) -> str:
        return f"{self.surrogate}+{self.sampler}"


#: The backend used when neither the call nor the spec names one (the measured comparison,
#: ``benchmarks/inference_backends.py``, chose it).
DEFAULT_INFERENCE = Inference("hand", "hand")


def parse_inference(value) -> Inference:
    """An inference backend from its name, ``"SURROGATE+SAMPLER"`` (``"sklearn+emcee"``), or as given.

    Parameters
    ----------
    value : str, Inference or None
        ``"SURROGATE+SAMPLER"``; one name alone sets the surrogate (``"sklearn"``) or the sampler
        (``"emcee"``), the other part the default's; None = :data:`DEFAULT_INFERENCE`.

    Returns
    -------
    Inference
        The backend.

    Raises
    ------
    StudyError
        A name that is not one of :data:`~sim.identify.surrogate.SURROGATES` ×
        :data:`~sim.identify.posterior.SAMPLERS`.
    """
    if value is None:
        return DEFAULT_INFERENCE
    if isinstance(value, Inference):
        parts = (value.surrogate, value.sampler)
    else:
        text = str(value).strip().lower()
        parts = tuple(text.split("+"))
        if len(parts) == 1:
            parts = ((text, DEFAULT_INFERENCE.sampler) if text in SURROGATES and text != "hand"
                     else (DEFAULT_INFERENCE.surrogate, text) if text in SAMPLERS and text != "hand" else (text, text))
    if len(parts) != 2 or parts[0] not in SURROGATES or parts[1] not in SAMPLERS:
        raise StudyError(f"inference backend {str(value)!r} is not known: write SURROGATE+SAMPLER with the surrogate "
                         f"one of {', '.join(SURROGATES)} and the sampler one of {', '.join(SAMPLERS)} "
                         "(e.g. 'sklearn+emcee')")
    return Inference(*parts)


def _inference(spec, backend) -> Inference:
    return parse_inference(backend if backend is not None else getattr(spec, "inference", None))


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


def _surrogates(spec, units, values, sigma, backend=None) -> tuple[list, dict]:
    surrogate = _inference(spec, backend).surrogate
    models, cv = [], {}
    for j, f in enumerate(spec.fitted):
        ok = np.isfinite(values[:, j])
        gp = fit_surrogate(units[ok], values[ok, j], seed=spec.seed, surrogate=surrogate)
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


def fit_posterior(spec, records: list[dict], warn=None, *, backend=None) -> dict:
    """The posterior of ``spec``'s free parameters from its design runs (module docstring).

    Parameters
    ----------
    spec : sim.identify.spec.IdentifySpec
        The spec.
    records : list of dict
        The design runs' records (:func:`sim.identify.runs.run_one`), in run order: the Latin
        hypercube's ``spec.runs`` first, then the refinement runs (if any).
    warn : callable, optional
        Receives the fallback's reason or the sampler's non-convergence, one line.
    backend : str or Inference, optional
        The inference backend (:func:`parse_inference`); default the spec's ``inference``
        attribute when it has one, else :data:`DEFAULT_INFERENCE`.

    Returns
    -------
    dict
        ``inference`` (``"SURROGATE+SAMPLER"``), ``method`` (``surrogate`` or ``abc``), ``fallback``
        (why ABC, or ""), ``surrogate_cv_error``
        (per fitted figure: ``n``, ``rmse``, ``noise``, ``error``, ``z_rms``, ``uncertainty``, ``ok``,
        ``scale``, ``length``), ``noise_correlation``, ``mcmc`` (``chains``, ``steps``, ``acceptance``,
        ``rhat``, ``converged`` (max R̂ ≤ :data:`RHAT_LIMIT`; a warning when not); with emcee also
        ``autocorr_steps``) or ``abc`` diagnostics, ``summary``
        (:func:`sim.identify.posterior.summarise`), ``samples`` (unit coordinates, at most
        :data:`MAX_SAMPLES_KEPT`), ``weights`` (ABC) and ``draws`` (the held-out runs' unit
        coordinates).

    Raises
    ------
    StudyError
        A fitted figure that too few design runs measured; an unknown backend.
    """
    from threadpoolctl import threadpool_limits

    inference = _inference(spec, backend)
    units, values = _design_arrays(spec, records)
    _check_measured(spec, records, values)
    with threadpool_limits(limits=1, user_api="blas"):     # small matrices: one thread is the fastest
        return _fit(spec, units, values, warn, inference)


def refinement_draws(spec, records: list[dict], *, backend=None) -> list[list[float]]:
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
    backend : str or Inference, optional
        As :func:`fit_posterior`'s.

    Returns
    -------
    list of list of float
        ``spec.refine`` unit coordinates.

    Raises
    ------
    StudyError
        A fitted figure that too few runs measured; an unknown backend.
    """
    from threadpoolctl import threadpool_limits

    inference = _inference(spec, backend)
    units, values = _design_arrays(spec, records)
    _check_measured(spec, records, values)
    with threadpool_limits(limits=1, user_api="blas"):
        obs, sigma = observed_on_scale(spec)
        models, _ = _surrogates(spec, units, values, sigma, inference)
        lik = Likelihood(models, obs, sigma, _residual_correlation(models, values))

        def tempered(u):
            return lik(u) / REFINE_TEMPER
        chain = run_sampler(inference.sampler, tempered, spec.parameters, _starts(spec, tempered, units),
                            spec.seed + 1)
        return _draws(spec, chain["samples"], spec.refine, 0x4EF1).tolist()


def _fit(spec, units: np.ndarray, values: np.ndarray, warn, inference: Inference) -> dict:
    obs, sigma = observed_on_scale(spec)
    models, cv = _surrogates(spec, units, values, sigma, inference)
    out = {"inference": str(inference), "surrogate_cv_error": cv, "fallback": "", "observed": obs.tolist(),
           "sigma": sigma.tolist()}
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
    chain = run_sampler(inference.sampler, lik, spec.parameters, _starts(spec, lik, units), spec.seed)
    samples = chain["samples"]
    mcmc = {"chains": chain["chains"], "steps": chain["steps"], "acceptance": chain["acceptance"],
            "rhat": [float(x) for x in chain["rhat"]]}
    if "autocorr_steps" in chain:
        mcmc["autocorr_steps"] = chain["autocorr_steps"]
    mcmc["converged"] = bool(max(mcmc["rhat"]) <= RHAT_LIMIT)
    if not mcmc["converged"] and warn:
        worst = int(np.argmax(mcmc["rhat"]))
        warn(f"the {inference.sampler} sampler has not converged (split R̂ {mcmc['rhat'][worst]:.2f} > {RHAT_LIMIT} "
             f"for {spec.parameters[worst].key}): the intervals are not the posterior's; a longer chain or more "
             "figures would be needed")
    out.update(method="surrogate", noise_correlation=corr.tolist(), summary=summarise(spec.parameters, samples),
               mcmc=mcmc,
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
