"""First-order analytic error propagation of a tolerance study: finite differences, no rendering.

For every toleranced key ``x_k`` of the design, the noise-free geometric twin
(:class:`sim.study.geometric.GeometricTwin`: the exact stripe per row through
the same scenarios, the pipeline's calibration, axis, reconstruction and
VDI/VDE 2634-2 evaluation) is evaluated at the design and at
``x_k = m·σ_k`` for m in :data:`MULTIPLES` (σ_k the tolerance's standard
deviation; a magnitude key, drawn as ``|x|``, at :data:`MAGNITUDE_MULTIPLES`),
every other key at its design value.  Per output Y (:data:`sim.study.outputs.OUTPUTS`):

* ``jacobian`` ∂Y/∂x_k: the central difference ``(Y(σ) − Y(−σ))/(2σ)``
  (one-sided ``(Y(σ) − Y(0))/σ`` for a magnitude) — the Jacobian of the
  calibration constants (``err.*``), of the reconstructed points (the sheet
  field error, the axis) and of the quality parameters with respect to each key;
* ``curvature`` ∂²Y/∂x_k²: ``(Y(σ) − 2Y(0) + Y(−σ))/σ²``;
* ``std_linear``: ``√Σ_k (J_k σ_k)²``, the first-order standard deviation of Y;
* ``shares``: ``(J_k σ_k)²/Σ_j (J_j σ_j)²`` (:func:`scheimpflug.sensitivity.linear_shares`),
  the first-order Sobol indices of the linearised model.

``responses`` keeps every evaluated point, for the tolerance limits and the
plots.  A key that changes no output at all has no geometric effect
(``geometric_effect`` false: a radiometric key — power, exposure, noise,
speckle — that only the rendered Monte Carlo sees).  Outputs that are ranges
(PF, F) are not differentiable at a perfect rig: their "Jacobian" is the slope
of a V and the first order understates them; the signed outputs (SD, PS, the
calibration constants) are smooth.
"""

from __future__ import annotations

import math
import time

import numpy as np

from scheimpflug.callbacks import ProgressCallback, report
from scheimpflug.errors import ScheimpflugError
from scheimpflug.model.binning import binned_rig
from scheimpflug.model.rig import rig_from_dict
from scheimpflug.sensitivity import linear_shares

from .geometric import GeometricTwin
from .outputs import OUTPUTS, measured_outputs
from .spec import StudySpec, _with_value, calibration_options

__all__ = ["MAGNITUDE_MULTIPLES", "MULTIPLES", "propagate"]

#: Where each signed key is evaluated, in units of its tolerance's σ [-].
MULTIPLES = (-2.0, -1.0, 1.0, 2.0)
#: Where each magnitude key (drawn as |x|) is evaluated, in units of σ [-].
MAGNITUDE_MULTIPLES = (0.5, 1.0, 2.0)


def _evaluate(twin: GeometricTwin, tables: dict, nominal_b, binning: int) -> dict:
    try:            # a point outside the rig's range (f − 2σ < 0 …) is a point not measured, not the end
        rig = rig_from_dict(tables)
        res = twin.evaluate(rig)
    except (ScheimpflugError, ValueError):
        return dict.fromkeys(OUTPUTS)
    out = measured_outputs(res, binned_rig(rig, binning), nominal_b, binning)
    out.update({k: res.get(k) for k in ("field_rms_mm", "field_max_mm")})
    return {k: out.get(k) for k in OUTPUTS}


def _num(x) -> float:
    return math.nan if x is None else float(x)


def _derivatives(points: dict, sigma: float, magnitude: bool, name: str) -> tuple[float, float]:
    y = {m: _num(points[m][name]) for m in points}
    if magnitude:
        return (y[1.0] - y[0.0]) / sigma, (y[2.0] - 2 * y[1.0] + y[0.0]) / sigma ** 2
    return (y[1.0] - y[-1.0]) / (2 * sigma), (y[1.0] - 2 * y[0.0] + y[-1.0]) / sigma ** 2


def _twin(spec: StudySpec, nominal) -> GeometricTwin:
    a = spec.artefacts
    return GeometricTwin(nominal, kinds=a.kinds, binning=a.binning, quick=a.quick, frames=a.frames,
                         model=spec.model, exclude_fraction=a.exclude_fraction,
                         calibration_options=calibration_options(binned_rig(nominal, a.binning)))


def propagate(spec: StudySpec, progress: ProgressCallback | None = None) -> dict:
    """The analytic (first-order, finite-difference) propagation of a tolerance study.

    Parameters
    ----------
    spec : StudySpec
        A tolerance spec (:func:`sim.study.spec.load_study_spec`).
    progress : ProgressCallback, optional
        ``progress(done, total)`` over the evaluations.

    Returns
    -------
    dict
        JSON-ready (module docstring): ``nominal`` (outputs at the design), ``keys``,
        ``sigma`` (per key, its unit), ``responses`` (per key: ``x`` deviations and
        ``outputs`` per output name), ``jacobian``, ``curvature``, ``shares`` (per output, per
        key), ``std_linear`` (per output), ``geometric_effect`` (per key), ``evaluations``,
        ``seconds``.

    Raises
    ------
    ValueError
        For a sweep spec.
    ScheimpflugError
        When the design itself cannot measure its artefacts (nothing to propagate).
    """
    if spec.kind != "tolerance":
        raise ValueError("analytic propagation needs a tolerance spec")
    t0 = time.perf_counter()
    nominal = spec.base_rig()
    twin = _twin(spec, nominal)
    k = spec.artefacts.binning
    n_eval = 1 + sum(len(MAGNITUDE_MULTIPLES if t.magnitude else MULTIPLES) for t in spec.tolerances)
    report(progress, 0, n_eval)
    nominal_b = binned_rig(nominal, k)
    res0 = twin.evaluate(nominal)        # raises when the design cannot measure
    y0 = measured_outputs(res0, nominal_b, nominal_b, k)
    y0.update({n: res0.get(n) for n in ("field_rms_mm", "field_max_mm")})
    y0 = {n: y0.get(n) for n in OUTPUTS}
    done, responses, base = 1, {}, spec.rig_tables
    for t in spec.tolerances:
        value = _key_value(base, t.key)
        points = {0.0: y0}
        for m in (MAGNITUDE_MULTIPLES if t.magnitude else MULTIPLES):
            points[m] = _evaluate(twin, _with_value(base, t.key, value + m * t.sigma), nominal_b, k)
            done += 1
            report(progress, done, n_eval)
        responses[t.key] = points
    return _summarise(spec, y0, responses, n_eval, time.perf_counter() - t0)


def _key_value(tables: dict, key: str) -> float:
    tbl, _, leaf = key.partition(".")
    return float(tables[tbl][leaf])


def _summarise(spec: StudySpec, y0: dict, responses: dict, n_eval: int, seconds: float) -> dict:
    keys = [t.key for t in spec.tolerances]
    sigma = {t.key: t.sigma for t in spec.tolerances}
    jac, curv, shares, std = {}, {}, {}, {}
    for name in OUTPUTS:
        jac[name], curv[name] = {}, {}
        for t in spec.tolerances:
            j, c = _derivatives(responses[t.key], t.sigma, t.magnitude, name)
            jac[name][t.key], curv[name][t.key] = _clean(j), _clean(c)
        js = np.array([_num(jac[name][key]) for key in keys])
        ss = np.array([sigma[key] for key in keys])
        ok = np.all(np.isfinite(js))
        std[name] = _clean(float(np.sqrt(np.sum((js * ss) ** 2)))) if ok else None
        shares[name] = dict(zip(keys, map(float, linear_shares(js, ss)))) if ok else dict.fromkeys(keys)
    effect = {key: any(_changed(y0[n], responses[key][m][n]) for n in OUTPUTS for m in responses[key])
              for key in keys}
    curves = {key: {"x": [m * sigma[key] for m in sorted(responses[key])],
                    "outputs": {n: [responses[key][m][n] for m in sorted(responses[key])] for n in OUTPUTS}}
              for key in keys}
    return {"nominal": y0, "keys": keys, "sigma": sigma, "responses": curves, "jacobian": jac,
            "curvature": curv, "shares": shares, "std_linear": std, "geometric_effect": effect,
            "evaluations": n_eval, "seconds": seconds}


def _clean(x):
    return None if x is None or not math.isfinite(x) else float(x)


def _changed(a, b) -> bool:
    if a is None or b is None:
        return a is not b
    return abs(float(a) - float(b)) > 1e-12 * max(1.0, abs(float(a)))
