"""Identification (issue 28): the statistics against closed forms, the known-answer test through the twin, bad specs.

The known-answer test renders an "instrument" — the paper rig at f/11 and speckle contrast 0.6,
binned 8 × 8, with a hidden seed — measures its figures, and identifies it from them with
``scheimpflug identify`` on another seed stream: the 90 % intervals must hold the true values,
a parameter no fitted figure depends on (the rotary axis tilt: the plate frames never turn
the table) must come back flat, and the held-out figures must lie in their predictive intervals.
"""

from __future__ import annotations

import json
import math
import tomllib

import numpy as np
import pytest

from scheimpflug.app.cli import main
from sim.identify import fit_gp, parse_identify_spec
from sim.identify.fit import fit_posterior
from sim.identify.posterior import predictive_interval, run_mcmc, summarise
from sim.identify.spec import Parameter, plan_design

# ------------------------------------------------------------------ the statistics, no rendering


def test_gp_leave_one_out_closed_form_equals_refitting_without_the_run():
    rng = np.random.default_rng(1)
    x = rng.random((14, 2))
    z = np.sin(3 * x[:, 0]) + x[:, 1] + 0.05 * rng.standard_normal(14)
    gp = fit_gp(x, z, seed=0)
    mean, var = gp.loo()
    for i in (0, 5, 13):                         # the same hyperparameters, run i left out
        keep = np.arange(14) != i
        from sim.identify.surrogate import GaussianProcess, _kernel

        k = _kernel(x[keep], x[keep], gp.length, gp.signal, gp.linear) + gp.noise * np.eye(13)
        chol = np.linalg.cholesky(k)
        zs = (z[keep] - gp.z_mean) / gp.z_scale
        sub = GaussianProcess(x[keep], z[keep], gp.z_mean, gp.z_scale, gp.length, gp.signal, gp.linear, gp.noise,
                              chol, np.linalg.solve(k, zs))
        m, v = sub.predict(x[i:i + 1])
        assert mean[i] == pytest.approx(m[0], abs=1e-8)
        assert var[i] == pytest.approx(v[0] + gp.noise * gp.z_scale ** 2, rel=1e-6)


def test_gp_finds_the_noise_and_its_cross_validated_error_is_the_true_error():
    rng = np.random.default_rng(2)
    f = lambda x: -2.0 + 1.5 * x[:, 0] ** 1.3 + 0.6 * x[:, 0] * x[:, 1]  # noqa: E731
    x = rng.random((30, 2))
    z = f(x) + 0.1 * rng.standard_normal(30)
    gp = fit_gp(x, z, seed=0)
    cv = gp.cross_validation()
    xt = rng.random((4000, 2))
    true_error = float(np.sqrt(np.mean((gp.predict(xt)[0] - f(xt)) ** 2)))
    assert gp.noise_sd == pytest.approx(0.1, rel=0.3)
    assert cv["error"] < 0.1 and true_error < 0.1      # the mean is known better than one run's noise
    assert cv["error"] == pytest.approx(true_error, abs=0.04)
    assert 0.7 < cv["z_rms"] < 1.3


def test_predictive_interval_of_20_draws_holds_a_new_draw_905_times_in_1000():
    rng = np.random.default_rng(3)
    hits = 0
    trials = 4000
    for _ in range(trials):
        v = rng.standard_normal(21)
        pi = predictive_interval(list(v[:20]))
        hits += pi["lo90"] <= v[20] <= pi["hi90"]
    assert pi["coverage"] == pytest.approx(19 / 21)
    assert hits / trials == pytest.approx(19 / 21, abs=0.015)     # 3.2 σ of a binomial at 4000 trials
    short = predictive_interval([1.0] * 18 + [None, None])
    assert short["lo90"] is None and short["n"] == 18


def _gauss_loglik(mean, sd, rho):
    cov = np.array([[sd[0] ** 2, rho * sd[0] * sd[1]], [rho * sd[0] * sd[1], sd[1] ** 2]])
    inv = np.linalg.inv(cov)

    def loglik(u):
        r = u[:, :2] - mean
        return -0.5 * np.einsum("ni,ij,nj->n", r, inv, r)
    return loglik


def test_mcmc_recovers_a_gaussian_posterior_and_names_a_flat_parameter():
    params = [Parameter("a.x", 0.0, 1.0), Parameter("a.y", 0.0, 1.0), Parameter("a.flat", 10.0, 20.0)]
    loglik = _gauss_loglik(np.array([0.4, 0.6]), (0.05, 0.08), 0.7)
    chain = run_mcmc(loglik, params, np.full((16, 3), 0.5), seed=0)
    s = summarise(params, chain["samples"])
    x, y, flat = s["parameters"]
    assert x["mean"] == pytest.approx(0.4, abs=0.01) and y["mean"] == pytest.approx(0.6, abs=0.015)
    assert x["lo90"] == pytest.approx(0.4 - 1.6449 * 0.05, abs=0.012)       # closed form: ± 1.645 σ
    assert y["hi90"] == pytest.approx(0.6 + 1.6449 * 0.08, abs=0.02)
    assert s["correlation"][0][1] == pytest.approx(0.7, abs=0.05)
    assert x["identifiable"] and y["identifiable"] and not flat["identifiable"]
    assert flat["width_ratio"] == pytest.approx(1.0, abs=0.05)
    assert flat["lo90"] == pytest.approx(10.5, abs=0.3) and flat["hi90"] == pytest.approx(19.5, abs=0.3)
    assert max(chain["rhat"]) < 1.05


def _synthetic(uncertainty_cv: str, refine: int = 0, measured=(1.0, 1.0), **head):
    """The paper's cheap known answer (f/11, speckle contrast 0.6, 16 runs over two unknowns): the spec, its
    design runs' records from closed forms; ``measured`` scales the two observed figures, ``head`` adds
    ``[identify]`` keys."""
    raw = {"identify": {"seed": 3, "runs": 16, "refine": refine, **head},
           "rig": {"preset": "paper"},
           "parameters": {"lens.f_number": {"range": [4.0, 32.0], "prior": "log-uniform"},
                          "laser.speckle_contrast": {"range": [0.3, 1.0]}},
           "experiment": {"binning": 8},
           "fitted": {"stripe_peak_dn": {"measured": 16000 / 11 ** 2 * measured[0], "uncertainty": "5%"},
                      "stripe_peak_cv": {"measured": math.hypot(0.1, 0.072) * measured[1],
                                         "uncertainty": uncertainty_cv}}}
    spec = parse_identify_spec(raw)
    rng = np.random.default_rng(4)
    recs = []
    for p in plan_design(spec):
        n, c = p.values["lens.f_number"], p.values["laser.speckle_contrast"]
        recs.append({"run": p.index, "unit": list(p.unit), "reasons": {},
                     "figures": {"stripe_peak_dn": 16000 / n ** 2 * (1 + 0.002 * rng.standard_normal()),
                                 "stripe_peak_cv": math.hypot(0.1, 0.12 * c) * (1 + 0.03 * rng.standard_normal())}})
    return spec, recs


def test_a_surrogate_worse_than_the_measurement_falls_back_to_abc_and_says_so():
    spec, recs = _synthetic("0.1%")          # the twin itself scatters 3 %: no surrogate predicts it to 0.1 %
    said = []
    fit = fit_posterior(spec, recs, warn=said.append)
    cv = fit["surrogate_cv_error"]["stripe_peak_cv"]
    assert not cv["ok"] and cv["error"] >= cv["uncertainty"]
    assert fit["method"] == "abc" and "stripe_peak_cv" in fit["fallback"] and said == [fit["fallback"]]
    assert fit["abc"]["effective_sample_size"] >= 1.0
    assert len(fit["draws"]) == spec.posterior_draws
    good = fit_posterior(*_synthetic("5%"))
    assert good["method"] == "surrogate" and good["fallback"] == ""
    assert all(c["ok"] and c["error"] < c["uncertainty"] for c in good["surrogate_cv_error"].values())
    again = fit_posterior(*_synthetic("5%"))                   # deterministic for a seed (same machine)
    assert again["summary"] == good["summary"] and again["draws"] == good["draws"]  # exact: same run


def test_refinement_runs_go_where_the_first_fit_puts_the_posterior():
    from sim.identify.fit import refinement_draws

    spec, recs = _synthetic("5%", refine=8)
    units = np.array(refinement_draws(spec, recs))
    assert units.shape == (8, 2) and np.all((units >= 0) & (units <= 1))
    truth = spec.parameters[0].unit(11.0)                # the f-number the figures were made at
    spread = np.std([r["unit"][0] for r in recs])          # the Latin hypercube's: 0.29
    assert np.all(np.abs(units[:, 0] - truth) < 0.1) and spread > 0.25
    assert len({tuple(u) for u in units.tolist()}) == 8


# ------------------------------------------------------------------ bad specs: one line each


_GOOD = """
[identify]
runs = 10
[rig]
preset = "paper"
[parameters]
"lens.f_number" = { range = [4.0, 32.0], prior = "log-uniform" }
[experiment]
binning = 8
[fitted]
C_sigma_mm = { measured = 0.2, uncertainty = "15%" }
[held_out]
F2_sigma_px_mm = { measured = 10.0 }
"""


@pytest.mark.parametrize("change, message", [
    (('[held_out]\nF2_sigma_px_mm = { measured = 10.0 }', '[held_out]\nC_sigma_mm = { measured = 0.2 }'),
     "figure 'C_sigma_mm' is in [fitted] and in [held_out]"),
    (('{ range = [4.0, 32.0], prior = "log-uniform" }', '{ prior = "log-uniform" }'),
     "a free parameter needs its prior range"),
    (('"lens.f_number" = { range = [4.0, 32.0], prior = "log-uniform" }',
      '"laser.speckle_contrast" = { range = [0.3, 1.5] }'),
     "leaves the key's physical range [0, 1]"),
    (('C_sigma_mm = { measured = 0.2, uncertainty = "15%" }', 'C_sigma_mm = { measured = 0.2 }'),
     "a fitted figure needs its uncertainty"),
    (('C_sigma_mm = {', 'C_sigma = {'), "unknown figure"),
    (('range = [4.0, 32.0]', 'range = [32.0, 4.0]'), "is reversed"),
    (('runs = 10', 'runs = 4'), "needs at least 8 runs"),
    (('runs = 10', 'runs = 10\nposterior_draws = 10'), "must be in [20, 1000]"),
    (('"lens.f_number" = {', '"lens.f_numbr" = {'), "did you mean 'lens.f_number'"),
    (('C_sigma_mm = { measured = 0.2, uncertainty = "15%" }',
      'endpoint_r2 = { measured = 0.9998, uncertainty = "1%" }'), "a percentage of an R² is not meaningful"),
    (('preset = "paper"', 'preset = "paper"\nset = { "lens.f_number" = 8.0 }'),
     "given in [rig.set] and in [parameters]"),
])
def test_a_bad_spec_is_one_line_and_writes_nothing(tmp_path, capsys, change, message):
    old, new = change
    assert old in _GOOD
    spec = tmp_path / "bad.toml"
    spec.write_text(_GOOD.replace(old, new))
    out = tmp_path / "out"
    assert main(["identify", str(spec), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err and "Traceback" not in err
    assert not out.exists()


# ------------------------------------------------------------------ the known-answer test, through the twin

_TRUTH = {"lens.f_number": 11.0, "laser.speckle_contrast": 0.6, "stage.axis_tilt_deg": 0.2}
_HIDDEN_SEED = 987654321        # the instrument's own noise, not in the identification's seed stream


@pytest.fixture(scope="module")
def known_answer(tmp_path_factory):
    from scheimpflug.model.rig import load_preset
    from sim.identify.runs import measure_rig
    from sim.identify.spec import Experiment

    root = tmp_path_factory.mktemp("identify")
    cal = {"steps": 5, "step_mm": 52.0, "start_mm": 31.0}
    rig = load_preset("paper").replace(lens={"f_number": 11.0}, laser={"speckle_contrast": 0.6},
                                       stage={"axis_tilt_deg": 0.2})
    figs, _ = measure_rig(rig, ("calibration",), Experiment(binning=8, calibration=cal), root / "instrument",
                          seed=_HIDDEN_SEED)
    spec = root / "spec.toml"
    spec.write_text(f"""
[identify]
seed = 7
runs = 24
posterior_draws = 20
name = "known answer"
[rig]
preset = "paper"
[parameters]
"lens.f_number" = {{ range = [4.0, 32.0], prior = "log-uniform" }}
"laser.speckle_contrast" = {{ range = [0.3, 1.0] }}
"stage.axis_tilt_deg" = {{ range = [0.0, 0.5] }}
[experiment]
binning = 8
calibration = {{ steps = 5, step_mm = 52.0, start_mm = 31.0 }}
[fitted]
stripe_peak_dn = {{ measured = {figs['stripe_peak_dn']!r}, uncertainty = "5%" }}
stripe_peak_cv = {{ measured = {figs['stripe_peak_cv']!r}, uncertainty = "5%" }}
[held_out]
F2_sigma_px_mm = {{ measured = {figs['F2_sigma_px_mm']!r} }}
C_sigma_mm = {{ measured = {figs['C_sigma_mm']!r} }}
""")
    out = root / "run"
    return spec, out, figs


def _identify(capsys, spec, out) -> dict:
    assert main(["identify", str(spec), "--out", str(out), "--quiet", "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_known_answer_intervals_hold_the_truth_and_the_unused_parameter_is_flat(known_answer, capsys):
    spec, out, figs = known_answer
    res = _identify(capsys, spec, out)
    params = {p["key"]: p for p in res["parameters"]}
    for key, truth in _TRUTH.items():
        p = params[key]
        assert p["lo90"] <= truth <= p["hi90"], (key, p)
        assert set(p) >= {"key", "mean", "lo90", "hi90", "identifiable"}
    assert params["lens.f_number"]["identifiable"] and params["laser.speckle_contrast"]["identifiable"]
    assert params["lens.f_number"]["hi90"] - params["lens.f_number"]["lo90"] < 2.0      # f/11 to ± 1 stop / 3
    assert not params["stage.axis_tilt_deg"]["identifiable"]              # no plate frame turns the table
    assert params["stage.axis_tilt_deg"]["width_ratio"] > 0.9
    assert res["method"] == "surrogate" and res["fallback"] == ""
    for name, cv in res["surrogate_cv_error"].items():
        assert cv["ok"] and cv["error"] < cv["uncertainty"], name
    assert [h["figure"] for h in res["held_out"]] == ["F2_sigma_px_mm", "C_sigma_mm"]
    for h in res["held_out"]:
        assert set(h) >= {"figure", "measured", "predicted_lo90", "predicted_hi90", "inside"}
        assert h["draws_measured"] == 20 and h["inside"] is True, h
    assert res["runs"]["design"] == 24 and res["runs"]["held_out"] == 20
    rig = tomllib.loads((out / "identified.toml").read_text())
    assert rig["lens"]["f_number"] == pytest.approx(params["lens.f_number"]["mean"], rel=1e-3)
    assert "NOT identifiable" in (out / "identified.toml").read_text()
    from scheimpflug.model.rig import load_rig

    assert load_rig(out / "identified.toml").lens.f_number == rig["lens"]["f_number"]
    for name in ("report.md", "pairs.png", "predictive.png", "summary.json", "posterior.json"):
        assert (out / name).stat().st_size > 0, name


def test_known_answer_rerun_resumes_without_rendering_and_gives_the_same_result(known_answer, capsys):
    spec, out, _ = known_answer
    if not (out / "summary.json").is_file():
        _identify(capsys, spec, out)
    before = json.loads((out / "summary.json").read_text())
    held = sorted((out / "runs").iterdir())[-1]              # a held-out run lost (killed before it finished)
    import shutil

    shutil.rmtree(held)
    res = _identify(capsys, spec, out)
    after = json.loads((out / "summary.json").read_text())
    assert res["runs"]["done_now"] == 1                          # only the lost run is rendered again
    # exact: resume
    assert after["parameters"] == before["parameters"] and after["held_out"] == before["held_out"]


def test_every_experiment_measures_the_parts_it_renders(tmp_path):
    """The blocker, the pile and the cylinder through one run (8 × 8 binned, 15° steps), against the parts."""
    from scheimpflug.model.rig import load_preset
    from sim.identify.runs import measure_rig
    from sim.identify.spec import Experiment

    exp = Experiment(binning=8, calibration={"steps": 5, "step_mm": 52.0, "start_mm": 31.0}, pile_step_deg=15.0,
                     cylinder_step_deg=15.0)
    figs, why = measure_rig(load_preset("paper"), ("calibration", "blocker", "pile", "cylinder"), exp, tmp_path,
                            seed=0)
    assert why == {} and all(v is not None for v in figs.values())
    assert figs["axis_mm"] == pytest.approx(179.45, abs=0.1)               # the paper rig's axis
    assert figs["cylinder_diameter_mm"] == pytest.approx(100.0, abs=0.2)   # the Ø100 × 108 mm cylinder
    assert figs["cylinder_height_mm"] == pytest.approx(108.0, abs=1.0)
    assert 67.5 < figs["ring_diameter_mm"] < 69.5                           # knurl roots 68, crests 69 mm
    assert 0 < figs["box_plane_rmse_mm"] < 0.2 and 0 < figs["ring_mean_error_mm"] < 1.0
