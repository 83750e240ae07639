"""The identification's inference backends compared (issue 36 item 5): the hand-written Gaussian process and
random-walk Metropolis against scikit-learn's ``GaussianProcessRegressor`` and emcee's ensemble sampler.

    python benchmarks/inference_backends.py [--seeds 10] [--scan /path/to/identify] [--twin /path/to/twin]

For every backend (``hand`` / ``sklearn`` surrogate × ``hand`` / ``emcee`` sampler, through the one
:func:`sim.identify.fit.fit_posterior`):

(a) the paper identification's known-answer closed loop, built cheaply as ``tests/test_identify.py``
    builds its records (``_synthetic``: the stripe's peak ∝ 1/N², its modulation
    ``hypot(0.1, 0.12 c)``, the twin's own scatter 0.2 % and 3 %) — no rendering — with the
    rotary axis tilt as a third, unused unknown; per seed a true (N, c, tilt) drawn inside the
    priors, the instrument's figures one realisation of the twin's scatter times the declared
    5 % measurement error, 24 design runs: how many true values fall inside the 90 % intervals,
    the fit's wall time; and the runs needed — the fraction of seeds whose every surrogate passes
    its cross-validation (error below the measurement σ) with 5, 6, 8, 12 and 24 runs;
(b) the FabScan scan identification's stored design and refinement runs (``twin build``'s
    ``identify`` folder: ``runs/NNNNNN/run.json``, ``real.json``, ``identify_scan.json``): each
    backend goes through :mod:`sim.identify.scan`'s steps after the runs (the figures its
    surrogates follow, then the fit): per unknown the posterior median and 90 % interval,
    per figure the surrogate's cross-validated error over the measurement σ, the sampler's
    R̂ and acceptance, the wall time; both samplers also with ``--long-chains`` × the steps. The
    refinement runs were placed by the hand backend.

Prints the tables (markdown) and the load average before and after.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

BACKENDS = ("hand+hand", "sklearn+hand", "hand+emcee", "sklearn+emcee")
TRUTH_KEYS = ("lens.f_number", "laser.speckle_contrast", "stage.axis_tilt_deg")
RUNS_TRIED = (5, 6, 8, 12, 24)
SCAN_RUNS_TRIED = (25, 50)           # (b): the first 25, the Latin hypercube's 50 (all 75: the table)
TWIN_SCATTER = {"stripe_peak_dn": 0.002, "stripe_peak_cv": 0.03}      # the twin's own, relative
DECLARED = 0.05                                                    # the measurement's, "5%"


# ------------------------------------------------------------------ (a) the known-answer closed loop


def _means(n: float, c: float) -> dict:
    return {"stripe_peak_dn": 16000.0 / n ** 2, "stripe_peak_cv": math.hypot(0.1, 0.12 * c)}


def _truth(seed: int) -> dict:
    rng = np.random.default_rng(np.random.SeedSequence((seed, 0x7A07)))
    return {"lens.f_number": float(np.exp(rng.uniform(np.log(6.0), np.log(24.0)))),
            "laser.speckle_contrast": float(rng.uniform(0.4, 0.9)),
            "stage.axis_tilt_deg": float(rng.uniform(0.05, 0.45))}


def _closed_loop(seed: int, runs: int):
    """The spec (instrument's figures at the seed's truth) and the twin's design runs' records."""
    from dataclasses import replace

    from sim.identify import parse_identify_spec
    from sim.identify.spec import plan_design

    truth = _truth(seed)
    rng = np.random.default_rng(np.random.SeedSequence((seed, 0x1257)))      # the instrument's noise
    measured = {k: v * math.exp(TWIN_SCATTER[k] * rng.standard_normal() + DECLARED * rng.standard_normal())
                for k, v in _means(truth["lens.f_number"], truth["laser.speckle_contrast"]).items()}
    raw = {"identify": {"seed": seed, "runs": max(runs, 15), "refine": 0},
           "rig": {"preset": "paper"},
           "parameters": {"lens.f_number": {"range": [4.0, 32.0], "prior": "log-uniform"},
                          "laser.speckle_contrast": {"range": [0.3, 1.0]},
                          "stage.axis_tilt_deg": {"range": [0.0, 0.5]}},
           "experiment": {"binning": 8},
           "fitted": {k: {"measured": v, "uncertainty": f"{100 * DECLARED:g}%"} for k, v in measured.items()}}
    spec = replace(parse_identify_spec(raw), runs=runs)      # fewer than the spec's 15 for "runs needed"
    twin = np.random.default_rng(np.random.SeedSequence((seed, 0x7314)))     # the twin's runs' noise
    records = []
    for p in plan_design(spec):
        m = _means(p.values["lens.f_number"], p.values["laser.speckle_contrast"])
        figs = {k: v * math.exp(TWIN_SCATTER[k] * twin.standard_normal()) for k, v in m.items()}
        records.append({"run": p.index, "unit": list(p.unit), "reasons": {}, "figures": figs})
    return spec, records, truth


def _surrogates_pass(spec, records, surrogate: str) -> tuple[bool, list]:
    from sim.identify.fit import _design_arrays, _surrogates, observed_on_scale

    units, values = _design_arrays(spec, records)
    _, sigma = observed_on_scale(spec)
    _, cv = _surrogates(spec, units, values, sigma, f"{surrogate}+hand")
    return all(c["ok"] for c in cv.values()), [c["error"] / c["uncertainty"] for c in cv.values()]


def known_answer(seeds: int) -> dict:
    """Part (a): calibration and wall time at 24 runs per backend; runs needed per surrogate."""
    from threadpoolctl import threadpool_limits

    from sim.identify.fit import fit_posterior

    out = {b: {"inside": 0, "values": 0, "identifiable_inside": 0, "identifiable": 0, "abc": 0, "wall": [],
               "width_n": [], "rhat": []} for b in BACKENDS}
    for s in range(seeds):
        spec, records, truth = _closed_loop(s, 24)
        for b in BACKENDS:
            t0 = time.perf_counter()
            fit = fit_posterior(spec, records, backend=b)
            o = out[b]
            o["wall"].append(time.perf_counter() - t0)
            o["abc"] += fit["method"] == "abc"
            for p in fit["summary"]["parameters"]:
                hit = p["lo90"] <= truth[p["key"]] <= p["hi90"]
                o["inside"] += hit
                o["values"] += 1
                if p["key"] != "stage.axis_tilt_deg":
                    o["identifiable"] += 1
                    o["identifiable_inside"] += hit
                if p["key"] == "lens.f_number":
                    o["width_n"].append(p["hi90"] - p["lo90"])
            if fit.get("mcmc"):
                o["rhat"].append(max(fit["mcmc"]["rhat"]))
        print(f"  (a) seed {s}: truth N {truth['lens.f_number']:.2f}, c {truth['laser.speckle_contrast']:.2f}; "
              + ", ".join(f"{b} {out[b]['inside']}/{out[b]['values']}" for b in BACKENDS), flush=True)
    needed = {}
    with threadpool_limits(limits=1, user_api="blas"):
        for surrogate in ("hand", "sklearn"):
            for n in RUNS_TRIED:
                passed, ratios, wall = 0, [], 0.0
                for s in range(seeds):
                    spec, records, _ = _closed_loop(s, n)
                    t0 = time.perf_counter()
                    ok, r = _surrogates_pass(spec, records, surrogate)
                    wall += time.perf_counter() - t0
                    passed += ok
                    ratios += r
                needed[(surrogate, n)] = {"passed": passed, "ratio_median": float(np.median(ratios)),
                                          "ratio_max": float(np.max(ratios)), "wall_per_fit": wall / seeds}
    return {"fits": out, "needed": needed}


def print_known_answer(res: dict, seeds: int) -> None:
    print(f"\n### (a) Known-answer closed loop, {seeds} seeds, 24 design runs, 3 unknowns (N, c identifiable; the "
          "axis tilt unused)\n")
    print("| backend | true values inside the 90 % intervals | of N and c | fell back to ABC | 90 % width of N "
          "(median) | max R̂ (worst seed) | fit wall, median (max) |")
    print("|---|---|---|---|---|---|---|")
    for b, o in res["fits"].items():
        print(f"| {b} | {o['inside']} / {o['values']} | {o['identifiable_inside']} / {o['identifiable']} | "
              f"{o['abc']} | {np.median(o['width_n']):.2f} | {max(o['rhat']) if o['rhat'] else float('nan'):.3f} | "
              f"{np.median(o['wall']):.1f} s ({max(o['wall']):.1f} s) |")
    print(f"\nRuns needed: seeds (of {seeds}) whose every surrogate passes its cross-validation (error < "
          "measurement σ); the error / σ over figures and seeds, median (max); one fit of both surrogates:\n")
    print("| surrogate | " + " | ".join(f"{n} runs" for n in RUNS_TRIED) + " |")
    print("|---|" + "---|" * len(RUNS_TRIED))
    for surrogate in ("hand", "sklearn"):
        cells = []
        for n in RUNS_TRIED:
            r = res["needed"][(surrogate, n)]
            cells.append(f"{r['passed']}/{seeds}, {r['ratio_median']:.2f} ({r['ratio_max']:.2f}), "
                         f"{r['wall_per_fit']:.2f} s")
        print(f"| {surrogate} | " + " | ".join(cells) + " |")


# ------------------------------------------------------------------ (b) the FabScan scan identification


def _scan_spec_type():
    from sim.identify.scan import ScanSpec

    @dataclass(frozen=True)
    class _Spec(ScanSpec):
        inference: str = "hand+hand"         # read by sim.identify.fit (getattr(spec, "inference"))
    return _Spec


def _scan_inputs(folder: Path, twin: Path):
    from dataclasses import replace

    from scheimpflug.model.rig import load_rig, rig_to_dict
    from sim.identify.scan import _figure_specs, _observed, _parameters

    meta = json.loads((folder / "identify_scan.json").read_text())
    setup = meta["setup"]
    tables = rig_to_dict(load_rig(twin / "rig.toml"))
    params = _parameters(setup["unknowns"], tables)
    records = []
    for run in sorted((folder / "runs").iterdir()):
        rec = json.loads((run / "run.json").read_text())
        if rec["role"] in ("design", "refine"):
            records.append(rec)
    real = json.loads((folder / "real.json").read_text())
    observed = _observed(real["fit"])
    design = [r for r in records if r["role"] == "design"]
    fitted, dropped = _figure_specs(observed, design, max(5, len(params) + 2))
    spec = _scan_spec_type()(name="scan", seed=setup["seed"], runs=setup["runs"], refine=setup["refine"],
                             posterior_draws=20, method="surrogate", parameters=params, fitted=fitted,
                             rig_tables=tables, rig_source="twin rig.toml")
    return spec, records, dropped, replace


def fabscan(folder: Path, twin: Path, long_chains: int = 4) -> dict:
    """Part (b): each backend through scan.py's steps after the runs."""
    from threadpoolctl import threadpool_limits

    from sim.identify.fit import _design_arrays, _surrogates, fit_posterior, observed_on_scale
    from sim.identify.scan import _followed

    base, records, dropped0, replace = _scan_inputs(folder, twin)
    out = {"records": len(records), "unknowns": [p.key for p in base.parameters], "cv": {}, "fits": {}}
    for surrogate in ("hand", "sklearn"):
        spec = replace(base, inference=f"{surrogate}+hand")
        units, values = _design_arrays(spec, records)
        _, sigma = observed_on_scale(spec)
        t0 = time.perf_counter()
        with np.errstate(invalid="ignore", divide="ignore"), threadpool_limits(limits=1, user_api="blas"):
            _, cv = _surrogates(spec, units, values, sigma)
        out["cv"][surrogate] = {"wall": time.perf_counter() - t0, "figures": cv}
        print(f"  (b) {surrogate} surrogates of {len(cv)} figures: {out['cv'][surrogate]['wall']:.1f} s", flush=True)
        for n in SCAN_RUNS_TRIED:              # runs needed: the first n runs only
            with np.errstate(invalid="ignore", divide="ignore"), threadpool_limits(limits=1, user_api="blas"):
                ok = np.isfinite(values[:n]).sum(axis=0) >= max(5, units.shape[1] + 2)
                sub = replace(spec, fitted=tuple(f for f, good in zip(spec.fitted, ok) if good))
                _, cvn = _surrogates(sub, units[:n], values[:n][:, ok], sigma[ok])
            out["cv"][surrogate][n] = sum(c["ok"] for c in cvn.values()), len(cvn)
    stored = json.loads((folder / "posterior.json").read_text())
    out["stored"] = stored
    runs = [(b, b, 1) for b in BACKENDS] + [(f"{b}, {long}× steps", b, long) for b in ("hand+hand", "hand+emcee")
                                            for long in ((long_chains,) if long_chains > 1 else ())]
    for label, b, long in runs:
        spec = replace(base, inference=b)
        t0 = time.perf_counter()
        with np.errstate(invalid="ignore", divide="ignore"), _longer(long):
            spec = _followed(spec, records, dict(dropped0), lambda msg: None)
            fit = fit_posterior(spec, records)
        wall = time.perf_counter() - t0
        out["fits"][label] = {"wall": wall, "fitted": [f.name for f in spec.fitted], "fit": fit}
        m = fit.get("mcmc") or {}
        print(f"  (b) {label}: {fit['method']}, {len(spec.fitted)} figures, max R̂ "
              f"{max(m.get('rhat', [float('nan')])):.2f}, {wall:.1f} s", flush=True)
    return out


@contextlib.contextmanager
def _longer(factor: int):
    """Both samplers' burn-in and kept steps × ``factor`` (the thinning kept)."""
    from sim.identify import posterior as post

    names = ("BURN_STEPS", "KEEP_STEPS", "EMCEE_BURN", "EMCEE_KEEP")
    saved = {n: getattr(post, n) for n in names}
    for n in names:
        setattr(post, n, saved[n] * factor)
    try:
        yield
    finally:
        for n, v in saved.items():
            setattr(post, n, v)


def print_fabscan(res: dict) -> None:
    print(f"\n### (b) FabScan `scan-2_1`: the stored {res['records']} design + refinement runs, "
          f"{len(res['unknowns'])} unknowns\n")
    names = sorted(set(res["cv"]["hand"]["figures"]) | set(res["cv"]["sklearn"]["figures"]))
    print("Surrogates' leave-one-out error over the measurement σ (< 1: the figure can be fitted), "
          f"all {len(names)} measured figures; fitting them all: hand {res['cv']['hand']['wall']:.1f} s, "
          f"sklearn {res['cv']['sklearn']['wall']:.1f} s\n")
    for surrogate in ("hand", "sklearn"):
        cv = res["cv"][surrogate]
        passed = "; ".join(f"first {n} runs: {cv[n][0]} of {cv[n][1]}" for n in SCAN_RUNS_TRIED)
        print(f"Figures whose {surrogate} surrogate passes (error < σ) — {passed}; all {res['records']}: "
              f"{sum(c['ok'] for c in cv['figures'].values())} of {len(cv['figures'])}\n")
    print("| figure | σ (its scale) | hand: error / σ | z RMS | sklearn: error / σ | z RMS |")
    print("|---|---|---|---|---|---|")
    for n in names:
        h, k = res["cv"]["hand"]["figures"][n], res["cv"]["sklearn"]["figures"][n]
        print(f"| {n} | {h['uncertainty']:.3g} | {h['error'] / h['uncertainty']:.2f} | {h['z_rms']:.2f} | "
              f"{k['error'] / k['uncertainty']:.2f} | {k['z_rms']:.2f} |")
    print("\n| backend | figures fitted | method | sampler: chains × steps, acceptance, max R̂ | fit wall |")
    print("|---|---|---|---|---|")
    st = res["stored"]
    sm = st.get("mcmc") or {}
    print(f"| stored `posterior.json` (twin build) | {len(st['surrogate_cv_error'])} | {st['method']} | "
          f"{sm.get('chains')} × {sm.get('steps')}, {sm.get('acceptance', float('nan')):.3f}, "
          f"{max(sm.get('rhat', [float('nan')])):.2f} | – |")
    for b, f in res["fits"].items():
        m = f["fit"].get("mcmc") or {}
        tau = f" (autocorrelation ≤ {max(m['autocorr_steps']):.0f} steps)" if "autocorr_steps" in m else ""
        print(f"| {b} | {len(f['fitted'])} | {f['fit']['method']} | {m.get('chains')} × {m.get('steps')}, "
              f"{m.get('acceptance', float('nan')):.3f}, {max(m.get('rhat', [float('nan')])):.2f}{tau} | "
              f"{f['wall']:.0f} s |")
    print("\nPosterior median [90 % interval] per unknown (`–`: flat, not identifiable):\n")
    print("| unknown | prior | " + " | ".join(res["fits"]) + " |")
    print("|---|---|" + "---|" * len(res["fits"]))
    for i, key in enumerate(res["unknowns"]):
        cells = []
        for f in res["fits"].values():
            p = f["fit"]["summary"]["parameters"][i]
            flag = "" if p["identifiable"] else " –"
            cells.append(f"{p['median']:.3g} [{p['lo90']:.3g}, {p['hi90']:.3g}]{flag}")
        prior = f["fit"]["summary"]["parameters"][i]["prior"]
        print(f"| {key} | {prior['lo']:.3g}–{prior['hi']:.3g} | " + " | ".join(cells) + " |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--scan", type=Path, default=None,
                    help="a twin build's identify folder, TWIN_DIR/identify ((b) skipped without it)")
    ap.add_argument("--twin", type=Path, default=None, help="its twin folder (default: the scan folder's parent)")
    ap.add_argument("--skip-a", action="store_true")
    ap.add_argument("--long-chains", type=int, default=4,
                    help="(b) also hand and emcee with this many times the steps (1: not)")
    args = ap.parse_args()
    import emcee
    import sklearn

    print(f"scikit-learn {sklearn.__version__}, emcee {emcee.__version__}; load {os.getloadavg()[0]:.1f}", flush=True)
    t0 = time.perf_counter()
    a = None if args.skip_a else known_answer(args.seeds)
    b = None
    if args.scan is not None and (args.scan / "identify_scan.json").is_file():
        b = fabscan(args.scan, args.twin or args.scan.parent, args.long_chains)
    if a:
        print_known_answer(a, args.seeds)
    if b:
        print_fabscan(b)
    else:
        print(f"\n(b) skipped: no scan identification in {args.scan}")
    print(f"\ntotal {time.perf_counter() - t0:.0f} s; load average now {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
