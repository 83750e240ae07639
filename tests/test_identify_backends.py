"""The identification's inference backends (issue 36 item 5) against closed forms and a known answer.

Each surrogate fit (hand-written, scikit-learn) on a known smooth function: its prediction error
and its predictive interval of the mean against the function itself; its closed-form
leave-one-out against refitting without the run.  Each sampler (hand-written Metropolis, emcee)
on a 2-D Gaussian likelihood: mean, σ and correlation against the closed form within Monte-Carlo
tolerances.  :func:`sim.identify.fit.fit_posterior` with each backend on the paper's cheap known
answer (the stripe's peak ∝ 1/N², its modulation ``hypot(0.1, 0.12 c)``): the 90 % intervals hold
the true f-number and speckle contrast, and the outputs have the same form.  A bad backend name:
one :class:`StudyError` naming it.  The samplers' chains are shortened here (monkeypatched) to keep
the file within seconds.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_identify import _synthetic

from scheimpflug.errors import StudyError
from sim.identify import posterior as post
from sim.identify.fit import DEFAULT_INFERENCE, Inference, fit_posterior, parse_inference
from sim.identify.posterior import run_sampler, summarise
from sim.identify.spec import Parameter
from sim.identify.surrogate import fit_surrogate, matern52

pytest.importorskip("sklearn")
pytest.importorskip("emcee")


@pytest.fixture(autouse=True)
def one_blas_thread():
    """Small matrices: one BLAS thread, as :func:`sim.identify.fit.fit_posterior` runs them."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        yield


@pytest.fixture
def short_chains(monkeypatch):
    """Chains a quarter to a fifth as long as the defaults (enough for 2-3 parameters, not for ten)."""
    monkeypatch.setattr(post, "BURN_STEPS", 500)
    monkeypatch.setattr(post, "KEEP_STEPS", 1000)
    monkeypatch.setattr(post, "EMCEE_BURN", 250)
    monkeypatch.setattr(post, "EMCEE_KEEP", 600)


def _smooth(x: np.ndarray) -> np.ndarray:
    return np.sin(3.0 * x[:, 0]) + 0.8 * x[:, 1] ** 2


@pytest.mark.parametrize("surrogate", ["hand", "sklearn"])
def test_surrogate_predicts_a_smooth_function_and_its_interval_holds_it(surrogate):
    rng = np.random.default_rng(11)
    x = rng.random((40, 2))
    z = _smooth(x) + 0.05 * rng.standard_normal(40)
    gp = fit_surrogate(x, z, seed=0, surrogate=surrogate)
    xt = rng.random((2000, 2))
    mean, var = gp.predict(xt)
    err = mean - _smooth(xt)
    assert float(np.sqrt(np.mean(err ** 2))) < 0.05          # the mean known better than one run's noise
    inside = np.mean(np.abs(err) <= 1.6449 * np.sqrt(var))      # the 90 % interval of the mean holds the function
    assert 0.8 <= inside <= 1.0, inside
    assert gp.noise_sd == pytest.approx(0.05, rel=0.35)
    cv = gp.cross_validation()
    assert cv["error"] == pytest.approx(float(np.sqrt(np.mean(err ** 2))), abs=0.03)


def test_sklearn_leave_one_out_closed_form_equals_its_prediction_without_the_run():
    from dataclasses import replace

    from scipy.linalg import cho_solve

    rng = np.random.default_rng(12)
    x = rng.random((14, 2))
    z = _smooth(x) + 0.05 * rng.standard_normal(14)
    gp = fit_surrogate(x, z, seed=0, surrogate="sklearn")
    mean, var = gp.loo()
    for i in (0, 7, 13):                     # the same hyperparameters, run i left out
        keep = np.arange(14) != i
        zs = (z[keep] - gp.z_mean) / gp.z_scale
        k = gp.signal * matern52(x[keep], x[keep], gp.length) + gp.noise * np.eye(13)
        chol = np.linalg.cholesky(k)
        sub = replace(gp, x=x[keep], z=z[keep], chol=chol, alpha=cho_solve((chol, True), zs))
        m, v = sub.predict(x[i:i + 1])
        assert mean[i] == pytest.approx(m[0], abs=1e-8)
        assert var[i] == pytest.approx(v[0] + gp.noise * gp.z_scale ** 2, rel=1e-6)


@pytest.mark.parametrize("sampler", ["hand", "emcee"])
def test_sampler_recovers_a_2d_gaussian(sampler, short_chains):
    mean, sd, rho = np.array([0.4, 0.6]), np.array([0.05, 0.08]), 0.7
    cov = np.array([[sd[0] ** 2, rho * sd[0] * sd[1]], [rho * sd[0] * sd[1], sd[1] ** 2]])
    inv = np.linalg.inv(cov)

    def loglik(u):
        r = u - mean
        return -0.5 * np.einsum("ni,ij,nj->n", r, inv, r)
    params = [Parameter("a.x", 0.0, 1.0), Parameter("a.y", 0.0, 1.0)]
    chain = run_sampler(sampler, loglik, params, np.full((16, 2), 0.5), seed=1)
    s = chain["samples"]
    # Monte-Carlo tolerances: a few hundred effective samples at least → mean ± 0.2 σ, σ ± 10 %
    assert s.mean(axis=0) == pytest.approx(mean, abs=0.2 * sd.max())
    assert s.std(axis=0) == pytest.approx(sd, rel=0.1)
    assert np.corrcoef(s, rowvar=False)[0, 1] == pytest.approx(rho, abs=0.06)
    x = summarise(params, s)["parameters"][0]
    assert x["lo90"] == pytest.approx(0.4 - 1.6449 * 0.05, abs=0.015)
    assert max(chain["rhat"]) < 1.1
    assert set(chain) >= {"samples", "acceptance", "rhat", "chains", "steps"}


def _known_answer(**head):
    """The paper's cheap known answer (``tests/test_identify.py``'s), its observations 1 % and 3 % off the truth."""
    return _synthetic("5%", measured=(1.01, 0.97), **head)


@pytest.mark.parametrize("backend", ["sklearn+hand", "hand+emcee", "sklearn+emcee"])
def test_fit_posterior_with_each_backend_holds_the_known_answer(backend, short_chains):
    spec, recs = _known_answer(inference=backend)           # the spec's [identify] inference, as `identify` runs it
    fit = fit_posterior(spec, recs)
    assert fit["inference"] == backend and fit["method"] == "surrogate" and fit["fallback"] == ""
    truth = {"lens.f_number": 11.0, "laser.speckle_contrast": 0.6}
    for p in fit["summary"]["parameters"]:
        assert p["lo90"] <= truth[p["key"]] <= p["hi90"], (backend, p)
        assert p["identifiable"]
    n = fit["summary"]["parameters"][0]
    assert n["hi90"] - n["lo90"] < 2.0                  # f/11 pinned to ± 1/3 stop, as the hand backend does
    assert set(fit) >= {"surrogate_cv_error", "noise_correlation", "summary", "mcmc", "samples", "draws"}
    assert set(fit["mcmc"]) >= {"chains", "steps", "acceptance", "rhat"} and fit["mcmc"]["converged"]
    assert len(fit["draws"]) == spec.posterior_draws and np.asarray(fit["samples"]).shape[1] == 2


def test_the_backend_by_name_and_a_bad_name_is_one_clear_error():
    assert parse_inference(None) == DEFAULT_INFERENCE
    assert parse_inference("sklearn+emcee") == Inference("sklearn", "emcee")
    assert parse_inference("emcee") == Inference(DEFAULT_INFERENCE.surrogate, "emcee")
    assert parse_inference("sklearn") == Inference("sklearn", DEFAULT_INFERENCE.sampler)
    assert str(Inference("hand", "emcee")) == "hand+emcee"
    spec, recs = _known_answer()
    for bad in ("torch", "sklearn+metropolis", "sklearn+emcee+sbi", ""):
        with pytest.raises(StudyError, match="inference backend") as err:
            fit_posterior(spec, recs, backend=bad)
        assert "hand, sklearn" in str(err.value) and "hand, emcee" in str(err.value)
    assert spec.inference == str(DEFAULT_INFERENCE)
    assert _known_answer(inference="SKlearn+emcee")[0].inference == "sklearn+emcee"      # [identify] inference
    with pytest.raises(StudyError, match=r"spec: \[identify\] inference backend 'torch' is not known") as err:
        _known_answer(inference="torch")
    assert len(str(err.value).splitlines()) == 1
