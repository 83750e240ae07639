"""Identification specs (TOML): which rig, which unknowns, which figures fitted and which held out.

Format (example: ``studies/examples/identify-paper.toml``)::

    [identify]
    seed = 1                  # base seed: run k's parameter values and render seed derive from (seed, k)
    runs = 24                 # twin runs over the prior, the surrogate's design (>= 5 per free parameter)
    refine = 16               # optional: more runs where a first fit's posterior (tempered 4 × wider) is,
                              #   so that the surrogate is trained where it matters (default 0)
    posterior_draws = 20      # held-out figures: twin runs at this many posterior draws (>= 20)
    method = "surrogate"      # "surrogate": a Gaussian process per figure, MCMC on it (ABC on the design
                              #   runs if a surrogate's cross-validated error is not below the measurement's
                              #   uncertainty); "abc": ABC on the design runs
    inference = "hand+hand"   # optional: the surrogates' fit and the sampler, SURROGATE+SAMPLER — "hand" or
                              #   "sklearn" + "hand" or "emcee" (sim.identify.fit.parse_inference)
    keep_frames = false       # keep every run's frame folders
    name = "…"                # optional; description = "…"

    [rig]                     # the base rig, as a study's: preset = "…" or file = "RIG.toml", [rig.set]
    preset = "paper-as-built"

    [parameters]              # the free parameters: any continuous rig key with its prior range
    "lens.f_number" = { range = [4.0, 32.0], prior = "log-uniform" }
    "laser.speckle_contrast" = { range = [0.3, 1.0] }              # prior = "uniform" (default)
    "stage.axis_tilt_deg" = { range = [0.0, 0.2], prior = { normal = [0.05, 0.05] } }  # truncated

    [experiment]              # what the twin renders and how it is processed: as the instrument was
    binning = 1               # k × k binned sensor
    detector = "paper"        # calibrate --detector and axis --detector (default "cog")
    method = "paper"          # calibrate --method (default "best")
    stripe = "paper"          # reconstruct --method of the rotary scans (default "cog")
    calibration = { steps = 27, step_mm = 10.0, start_mm = -10.0 }   # default: the rig's plan
    pile_step_deg = 6.0       # rotary step of the pile scan (its figures only)
    cylinder_step_deg = 12.0  # rotary step of the cylinder scan (its figures only)
    spp = 32                  # optional: laser samples per lit row

    [fitted]                  # measured figures with their uncertainty (1 σ): a number in the figure's
    C_sigma_mm = { measured = 0.2014, uncertainty = "15%" }        #   unit or "N%" of the value
    endpoint_r2 = { measured = 0.9998, uncertainty = 0.00005 }

    [held_out]                # figures predicted, never fitted (uncertainty optional)
    box_plane_rmse_mm = { measured = 0.1775 }

The figures are the registry's (:data:`sim.identify.figures.FIGURES`).  The rig's
derived keys (stage layout, waist, exposure) are pinned to the base rig's, and so
is the calibration plan: every run is the same instrument with other values of
the free parameters, as a tolerance study's draws are.  A held-out figure that is
also fitted, a parameter without a range or with a range outside its key's
physical range (:data:`scheimpflug.model.rig.KEY_RANGES`) or one the rig
validation refuses, a fitted figure without an uncertainty, an unknown figure,
table or key — each is one :class:`scheimpflug.errors.StudyError` naming it,
before anything runs.

Seeds.  The design is a Latin hypercube in the prior's unit coordinates seeded by
``seed``; run k (design runs first, then the held-out runs) renders with
``sample_seed(seed, k)`` (the Latin hypercube's runs, then the refinement runs, then
the held-out runs): every run has its own noise, the twin's randomness that
the estimate treats as noise.  Nothing depends on the number of workers.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scheimpflug.errors import RenderError, RigError, StudyError
from scheimpflug.model.binning import binned_rig
from scheimpflug.model.rig import KEY_RANGES, key_in_range, read_toml, rig_from_dict, rig_to_dict

from ..dataset.spec import sample_seed
from ..study.spec import (
    _choice,
    _fail,
    _integer,
    _known,
    _num,
    _parse_rig,
    _pinned,
    _resolve,
    _rig_key,
    _with_value,
    calibration_options,
)
from .figures import EXPERIMENTS, FIGURES

__all__ = ["MAX_RUNS", "MIN_POSTERIOR_DRAWS", "RUNS_PER_PARAMETER", "Experiment", "FigureSpec", "IdentifySpec",
           "Parameter", "RunPlan", "load_identify_spec", "parse_identify_spec", "plan_design", "plan_design_units",
           "plan_run"]

#: The fewest design runs per free parameter (the surrogate's design) [-].
RUNS_PER_PARAMETER = 5
#: The most design runs (a Gaussian process is O(n³) in them) [-].
MAX_RUNS = 2000
#: The fewest held-out runs: a 90 % predictive interval from order statistics needs 19 [-].
MIN_POSTERIOR_DRAWS = 20
_MAX_POSTERIOR_DRAWS = 1000
_TOP = {"identify", "rig", "parameters", "experiment", "fitted", "held_out"}
_IDENTIFY_KEYS = {"seed", "runs", "refine", "posterior_draws", "method", "keep_frames", "name", "description",
                  "inference"}
_EXPERIMENT_KEYS = {"binning", "detector", "method", "stripe", "calibration", "pile_step_deg", "cylinder_step_deg",
                    "spp"}
_DETECTORS = ("cog", "gaussian3", "blais-rioux", "edge", "paper")
_CAL_METHODS = ("best", "paper", "refined")
_PRIORS = ("uniform", "log-uniform")


@dataclass(frozen=True)
class Parameter:
    """One free parameter: a rig key and its prior.

    Parameters
    ----------
    key : str
        ``"table.key"`` of the rig.
    lo, hi : float
        The prior range [key unit].
    prior : {"uniform", "log-uniform", "normal"}
        The prior's form (normal: truncated to the range).
    mean, sigma : float
        The normal prior's mean and σ [key unit] (NaN otherwise).
    """

    key: str
    lo: float
    hi: float
    prior: str = "uniform"
    mean: float = math.nan
    sigma: float = math.nan

    def value(self, q):
        """The value at unit coordinate q ∈ [0, 1] (log-uniform: geometric).

        Parameters
        ----------
        q : float or ndarray
            Unit coordinate [-].

        Returns
        -------
        float or ndarray
            The key's value [key unit].
        """
        q = np.asarray(q, dtype=np.float64)
        out = self.lo * (self.hi / self.lo) ** q if self.prior == "log-uniform" else self.lo + q * (self.hi - self.lo)
        return float(out) if out.ndim == 0 else out

    def unit(self, value):
        """Inverse of :meth:`value`.

        Parameters
        ----------
        value : float or ndarray
            The key's value [key unit].

        Returns
        -------
        float or ndarray
            Unit coordinate [-].
        """
        v = np.asarray(value, dtype=np.float64)
        out = np.log(v / self.lo) / np.log(self.hi / self.lo) if self.prior == "log-uniform" else \
            (v - self.lo) / (self.hi - self.lo)
        return float(out) if out.ndim == 0 else out

    def log_prior(self, q: np.ndarray) -> np.ndarray:
        """Log prior density over the unit coordinate, up to a constant; −∞ outside [0, 1].

        Parameters
        ----------
        q : ndarray
            Unit coordinates [-].

        Returns
        -------
        ndarray
            Same shape as ``q``.
        """
        q = np.asarray(q, dtype=np.float64)
        inside = (q >= 0.0) & (q <= 1.0)
        out = np.where(inside, 0.0, -np.inf)
        if self.prior == "normal":
            out = out - 0.5 * ((self.value(np.clip(q, 0, 1)) - self.mean) / self.sigma) ** 2
        return out

    def describe(self) -> str:
        """``[lo, hi] uniform`` / ``log-uniform`` / ``normal(m, s) truncated``.

        Returns
        -------
        str
            Short text for reports.
        """
        form = f"normal({self.mean:g}, {self.sigma:g}) truncated" if self.prior == "normal" else self.prior
        return f"[{self.lo:g}, {self.hi:g}] {form}"


@dataclass(frozen=True)
class FigureSpec:
    """A measured figure of the spec (fitted or held out).

    Parameters
    ----------
    name : str
        Its registry name (:data:`sim.identify.figures.FIGURES`).
    measured : float
        The instrument's value [figure unit].
    absolute : float or None
        Uncertainty (1 σ) in the figure's unit, or None.
    relative : float or None
        Uncertainty as a fraction of the value, or None.
    scale : {"log", "log1m", "linear"} or None
        Its statistical scale when it is not a registry figure (a scan's image-level figures,
        :mod:`sim.identify.scan`); None = the registry's.
    """

    name: str
    measured: float
    absolute: float | None = None
    relative: float | None = None
    scale: str | None = None

    @property
    def stat_scale(self) -> str:
        """The scale the surrogate and the likelihood use (its own, else the registry's)."""
        return self.scale or FIGURES[self.name].scale

    @property
    def has_uncertainty(self) -> bool:
        """Whether an uncertainty was given."""
        return self.absolute is not None or self.relative is not None

    @property
    def uncertainty(self) -> float | None:
        """The uncertainty in the figure's unit (None without one) [figure unit]."""
        if self.absolute is not None:
            return self.absolute
        return None if self.relative is None else self.relative * abs(self.measured)

    def describe(self) -> str:
        """``0.2014 ± 15 %`` or ``0.9998 ± 5e-05`` or ``0.1775``.

        Returns
        -------
        str
            Short text for reports.
        """
        if self.relative is not None:
            return f"{self.measured:g} ± {100 * self.relative:g} %"
        return f"{self.measured:g}" + (f" ± {self.absolute:g}" if self.absolute is not None else "")


@dataclass(frozen=True)
class Experiment:
    """What every run renders and how it processes it (the ``[experiment]`` table).

    Parameters
    ----------
    binning : int
        k × k binned sensor [-].
    detector, method, stripe : str
        ``calibrate --detector`` / ``axis --detector``, ``calibrate --method``, ``reconstruct --method``.
    calibration : dict
        Calibration scenario options (``steps``, ``step_mm``, ``start_mm``, ``plate_height_mm``).
    pile_step_deg, cylinder_step_deg : float
        Rotary steps of the scans [deg].
    spp : int or None
        Laser samples per lit row.
    """

    binning: int = 1
    detector: str = "cog"
    method: str = "best"
    stripe: str = "cog"
    calibration: dict = field(default_factory=dict)
    pile_step_deg: float = 6.0
    cylinder_step_deg: float = 12.0
    spp: int | None = None


@dataclass(frozen=True)
class IdentifySpec:
    """A parsed, validated identification spec (format in the module docstring).

    Parameters
    ----------
    raw : dict
        The spec as read (JSON-ready): the job's identity.
    folder : Path
        Folder of the spec file.
    name, description : str
        For the report.
    seed : int
        Base seed [-].
    runs : int
        Design runs of the Latin hypercube [-].
    refine : int
        Refinement runs at a first fit's tempered posterior [-].
    posterior_draws : int
        Held-out runs [-].
    method : {"surrogate", "abc"}
        The estimate.
    keep_frames : bool
        Keep the frame folders.
    rig_tables : dict
        The base rig, every key given (derived keys pinned).
    rig_source : str
        ``"preset:NAME"`` or ``"file:PATH"``.
    parameters : tuple of Parameter
        The free parameters, in spec order.
    experiment : Experiment
        What the runs render.
    fitted, held_out : tuple of FigureSpec
        The measured figures.
    inference : str
        The inference backend, ``SURROGATE+SAMPLER`` (:func:`sim.identify.fit.parse_inference`).
    """

    raw: dict
    folder: Path
    name: str
    description: str
    seed: int
    runs: int
    refine: int
    posterior_draws: int
    method: str
    keep_frames: bool
    rig_tables: dict
    rig_source: str
    parameters: tuple
    experiment: Experiment
    fitted: tuple
    held_out: tuple
    inference: str = "hand+hand"

    @property
    def keys(self) -> list[str]:
        """The free parameters' keys, in spec order."""
        return [p.key for p in self.parameters]

    def experiments(self, figures) -> tuple[str, ...]:
        """The experiments a run must render to measure ``figures`` (each with the ones it needs).

        Parameters
        ----------
        figures : iterable of FigureSpec
            The figures.

        Returns
        -------
        tuple of str
            A prefix-closed subset of :data:`sim.identify.figures.EXPERIMENTS`, in order.
        """
        needed = {FIGURES[f.name].experiment for f in figures}
        last = max((EXPERIMENTS.index(e) for e in needed), default=0)
        out = [e for e in EXPERIMENTS[:last + 1] if e in needed or e in ("calibration", "blocker")]
        return tuple(out)

    def sha256(self) -> str:
        """SHA-256 of the canonical JSON of :attr:`raw`.

        Returns
        -------
        str
            64 hex digits.
        """
        return hashlib.sha256(json.dumps(self.raw, sort_keys=True).encode()).hexdigest()

    def input_files(self) -> list[Path]:
        """The rig file, if the spec names one (resolved, existing).

        Returns
        -------
        list of Path
            Zero or one file.
        """
        if not self.rig_source.startswith("file:"):
            return []
        p = _resolve(self.folder, self.rig_source[5:])
        return [p] if p.is_file() else []


@dataclass(frozen=True)
class RunPlan:
    """What run k renders: everything a worker needs to run it alone.

    Parameters
    ----------
    index : int
        Run number k (design runs 0 … n−1, the refinement runs, then the held-out runs) [-].
    seed : int
        Render seed [-].
    rig : dict
        The run's full-size rig as nested tables.
    values : dict
        ``"table.key"`` → the run's value of every free parameter.
    unit : tuple of float
        The values' unit coordinates [-].
    role : {"design", "refine", "held-out"}
        Which phase the run belongs to.
    experiments : tuple of str
        The experiments it renders.
    experiment : Experiment
        How.
    keep_frames : bool
        Keep the frame folders.
    """

    index: int
    seed: int
    rig: dict
    values: dict
    unit: tuple
    role: str
    experiments: tuple
    experiment: Experiment
    keep_frames: bool


# ------------------------------------------------------------------ parsing


def load_identify_spec(path: str | os.PathLike) -> IdentifySpec:
    """Read and validate an identification spec file.

    Parameters
    ----------
    path : path
        The TOML spec.

    Returns
    -------
    IdentifySpec
        The validated spec.

    Raises
    ------
    StudyError
        A missing or unreadable file, invalid TOML, or anything :func:`parse_identify_spec` refuses.
    """
    p = Path(path)
    raw = read_toml(p, "spec file", StudyError)
    return parse_identify_spec(raw, folder=p.resolve().parent, where=str(p), default_name=p.stem)


def parse_identify_spec(raw: dict, folder: str | os.PathLike = ".", where: str = "spec",
                        default_name: str = "identification") -> IdentifySpec:
    """Validate an identification spec given as nested tables (module docstring).

    Parameters
    ----------
    raw : dict
        The spec's tables.
    folder : path
        Folder that relative paths resolve against.
    where : str
        Name of the spec in error messages.
    default_name : str
        Name when ``[identify] name`` is not given.

    Returns
    -------
    IdentifySpec
        The validated spec; every design run is planned and its rig checked.

    Raises
    ------
    StudyError
        One line naming the first problem (module docstring).
    """
    _known(where, "the spec", raw, _TOP)
    for table in _TOP & set(raw):
        if not isinstance(raw[table], dict):
            raise _fail(where, f"[{table}] must be a table")
    head = raw.get("identify", {})
    _known(where, "[identify]", head, _IDENTIFY_KEYS)
    folder = Path(folder)
    tables, source = _parse_rig(where, folder, raw.get("rig", {}))
    experiment = _parse_experiment(where, raw.get("experiment", {}))
    try:
        binned_rig(rig_from_dict(tables), experiment.binning)
    except (RigError, ValueError) as exc:
        raise _fail(where, f"experiment.binning = {experiment.binning}: {exc}") from None
    params = _parse_parameters(where, raw, tables)
    fitted, held_out = _parse_figures(where, raw)
    pinned = _pinned(tables, experiment.binning)
    base_b = binned_rig(rig_from_dict(pinned), experiment.binning)
    _check_spp(where, experiment.spp, base_b)
    if not experiment.calibration:
        experiment = _with_calibration(experiment, calibration_options(base_b))
    spec = IdentifySpec(raw=json.loads(json.dumps(raw)), folder=folder,
                        name=str(head.get("name", default_name)), description=str(head.get("description", "")),
                        rig_tables=pinned, rig_source=source, parameters=params, experiment=experiment,
                        fitted=fitted, held_out=held_out, **_parse_head(where, head, len(params)))
    units = plan_design_units(spec)
    for k in range(spec.runs):          # every design rig valid, or one error naming the run
        plan_run(spec, k, units[k], "design", where=where)
    return spec


def _check_spp(where: str, spp: int | None, rig_b) -> None:
    """``experiment.spp`` within the laser pass's memory budget (:mod:`sim.render_limits`)."""
    from ..render_limits import check_laser_samples

    if spp is not None:
        try:
            check_laser_samples(spp, rig_b.sensor.rows, rig_b.twin.bounces, "experiment.spp")
        except RenderError as exc:
            raise _fail(where, str(exc)) from None


def _with_calibration(e: Experiment, cal: dict) -> Experiment:
    from dataclasses import replace

    return replace(e, calibration=cal)


def _parse_head(where: str, head: dict, n_params: int) -> dict:
    seed = _integer(where, "identify.seed", head.get("seed", 0), 0)
    least = max(8, RUNS_PER_PARAMETER * n_params)
    runs = _integer(where, "identify.runs", head.get("runs", max(least, 24)), 1)
    if runs < least:
        raise _fail(where, f"identify.runs = {runs}: the surrogate of {n_params} free parameter"
                           f"{'s' if n_params != 1 else ''} needs at least {least} runs "
                           f"({RUNS_PER_PARAMETER} per parameter, 8 at least)")
    if runs > MAX_RUNS:
        raise _fail(where, f"identify.runs = {runs:,}: more than the limit of {MAX_RUNS:,} (the Gaussian "
                           "process is cubic in the runs)")
    refine = _integer(where, "identify.refine", head.get("refine", 0), 0)
    if refine > MAX_RUNS:
        raise _fail(where, f"identify.refine = {refine:,}: more than the limit of {MAX_RUNS:,}")
    draws = _integer(where, "identify.posterior_draws", head.get("posterior_draws", MIN_POSTERIOR_DRAWS), 1)
    if not MIN_POSTERIOR_DRAWS <= draws <= _MAX_POSTERIOR_DRAWS:
        raise _fail(where, f"identify.posterior_draws = {draws}: must be in [{MIN_POSTERIOR_DRAWS}, "
                           f"{_MAX_POSTERIOR_DRAWS}] (a 90 % predictive interval from order statistics "
                           "needs at least 19 draws)")
    keep = head.get("keep_frames", False)
    if not isinstance(keep, bool):
        raise _fail(where, f"identify.keep_frames = {keep!r}: must be true or false")
    from .fit import parse_inference

    try:
        inference = str(parse_inference(head.get("inference")))
    except StudyError as exc:
        raise _fail(where, f"[identify] {exc}") from None
    return {"seed": seed, "runs": runs, "refine": refine, "posterior_draws": draws, "keep_frames": keep,
            "method": _choice(where, "identify.method", head.get("method", "surrogate"), ("surrogate", "abc")),
            "inference": inference}


def _positive(where: str, key: str, value, upper: float = math.inf) -> float:
    if not (_num(value) and 0 < value <= upper):
        raise _fail(where, f"{key} = {value!r}: must be a number in (0, {upper:g}]")
    return float(value)


def _parse_experiment(where: str, table: dict) -> Experiment:
    _known(where, "[experiment]", table, _EXPERIMENT_KEYS)
    cal = table.get("calibration", {})
    if not isinstance(cal, dict):
        raise _fail(where, "experiment.calibration must be a table { steps = n, step_mm = s, start_mm = x }")
    _known(where, "experiment.calibration", cal, {"steps", "step_mm", "start_mm", "plate_height_mm"})
    opts = {}
    if cal:
        opts["steps"] = _integer(where, "experiment.calibration.steps", cal.get("steps", 9), 3)
        if opts["steps"] > 1000:
            raise _fail(where, f"experiment.calibration.steps = {opts['steps']:,}: more than 1,000 plate frames")
        for key in ("step_mm", "start_mm", "plate_height_mm"):
            if key in cal:
                value = cal[key]
                ok = _num(value) and (value > 0 if key != "start_mm" else abs(value) < 1e5)
                if not ok:
                    raise _fail(where, f"experiment.calibration.{key} = {value!r}: must be a "
                                       f"{'number > 0' if key != 'start_mm' else 'finite number'} [mm]")
                opts[key] = float(value)
    spp = table.get("spp")
    return Experiment(
        binning=_integer(where, "experiment.binning", table.get("binning", 1), 1),
        detector=_choice(where, "experiment.detector", table.get("detector", "cog"), _DETECTORS),
        method=_choice(where, "experiment.method", table.get("method", "best"), _CAL_METHODS),
        stripe=_choice(where, "experiment.stripe", table.get("stripe", "cog"), _DETECTORS),
        calibration=opts,
        pile_step_deg=_positive(where, "experiment.pile_step_deg", table.get("pile_step_deg", 6.0), 90.0),
        cylinder_step_deg=_positive(where, "experiment.cylinder_step_deg", table.get("cylinder_step_deg", 12.0),
                                    90.0),
        spp=None if spp is None else _integer(where, "experiment.spp", spp, 1))


def _range_text(key: str) -> str:
    table, _, leaf = key.partition(".")
    return KEY_RANGES.get(table, {}).get(leaf, "")


def _parse_prior(where: str, name: str, prior, lo: float, hi: float) -> dict:
    if prior is None or prior == "uniform":
        return {"prior": "uniform"}
    if prior == "log-uniform":
        if not lo > 0:
            raise _fail(where, f"{name}: a log-uniform prior needs a range above 0, got [{lo:g}, {hi:g}]")
        return {"prior": "log-uniform"}
    if isinstance(prior, dict) and set(prior) == {"normal"}:
        ms = prior["normal"]
        if isinstance(ms, list) and len(ms) == 2 and all(_num(v) for v in ms) and ms[1] > 0:
            return {"prior": "normal", "mean": float(ms[0]), "sigma": float(ms[1])}
    raise _fail(where, f"{name}: prior = {prior!r}: give \"uniform\", \"log-uniform\" or "
                       "{ normal = [MEAN, SIGMA] } (SIGMA > 0)")


def _parse_parameter(where: str, key: str, value, tables: dict) -> Parameter:
    name = f"parameters.{key!r}"
    base = _rig_key(where, "[parameters]", key, tables)
    if isinstance(base, int):
        raise _fail(where, f"{name}: an integer key cannot be a free parameter")
    if not isinstance(value, dict) or "range" not in value:
        raise _fail(where, f"{name} = {value!r}: a free parameter needs its prior range, "
                           "{ range = [lo, hi] } (and optionally prior = \"uniform\" | \"log-uniform\" | "
                           "{ normal = [MEAN, SIGMA] })")
    _known(where, name, value, {"range", "prior"})
    rng = value["range"]
    if not (isinstance(rng, list) and len(rng) == 2 and all(_num(v) for v in rng)):
        raise _fail(where, f"{name}: range must be [lo, hi] with two finite numbers, got {rng!r}")
    lo, hi = float(rng[0]), float(rng[1])
    if not lo < hi:
        raise _fail(where, f"{name}: the range [{lo:g}, {hi:g}] is {'empty' if lo == hi else 'reversed'} "
                           "(need lo < hi)")
    table, _, leaf = key.partition(".")
    for end in (lo, hi):
        if not key_in_range(table, leaf, end):
            raise _fail(where, f"{name}: the range [{lo:g}, {hi:g}] leaves the key's physical range "
                               f"{_range_text(key)} ({end:g})")
        try:
            rig_from_dict(_with_value(tables, key, end))
        except RigError as exc:
            raise _fail(where, f"{name}: the rig cannot take the end {end:g} of the range: {exc}") from None
    return Parameter(key, lo, hi, **_parse_prior(where, name, value.get("prior"), lo, hi))


def _parse_parameters(where: str, raw: dict, tables: dict) -> tuple:
    table = raw.get("parameters")
    if not table:
        raise _fail(where, "[parameters] is required and must name at least one free rig key")
    fixed = raw.get("rig", {}).get("set", {}) or {}
    out = []
    for key, value in table.items():
        if key in fixed:
            raise _fail(where, f"{key!r} is given in [rig.set] and in [parameters]: a free parameter takes "
                               "the values of its prior; remove it from [rig.set]")
        out.append(_parse_parameter(where, key, value, tables))
    return tuple(out)


def _uncertainty(where: str, name: str, value, scale: str) -> dict:
    if isinstance(value, str) and value.strip().endswith("%"):
        try:
            pct = float(value.strip()[:-1])
        except ValueError:
            pct = math.nan
        if not (math.isfinite(pct) and 0 < pct < 1000):
            raise _fail(where, f"{name}.uncertainty = {value!r}: a percentage must be in (0, 1000) %")
        if scale == "log1m":
            raise _fail(where, f"{name}.uncertainty = {value!r}: a percentage of an R² is not meaningful; give "
                               "it in the figure's unit (e.g. 0.00005 for R² = 0.9998 to its last digit)")
        return {"relative": pct / 100.0}
    if _num(value) and value > 0:
        return {"absolute": float(value)}
    raise _fail(where, f"{name}.uncertainty = {value!r}: give a number > 0 in the figure's unit or \"N%\"")


def _parse_figure(where: str, section: str, name: str, value, need_uncertainty: bool):
    label = f"{section}.{name!r}"
    if name not in FIGURES:
        raise _fail(where, f"{label}: unknown figure (known: {', '.join(FIGURES)})")
    if not isinstance(value, dict) or "measured" not in value:
        raise _fail(where, f"{label} = {value!r}: give {{ measured = VALUE"
                           f"{', uncertainty = U' if need_uncertainty else ''} }}")
    _known(where, label, value, {"measured", "uncertainty"})
    y = value["measured"]
    scale = FIGURES[name].scale
    if not (_num(y) and (scale == "linear" or (scale == "log" and y > 0) or (scale == "log1m" and y < 1))):
        need = {"log": "a number > 0", "log1m": "a number < 1", "linear": "a finite number"}[scale]
        raise _fail(where, f"{label}.measured = {y!r}: must be {need}")
    if "uncertainty" not in value:
        if need_uncertainty:
            raise _fail(where, f"{label}: a fitted figure needs its uncertainty (uncertainty = U in "
                               f"{FIGURES[name].unit}, or \"N%\"): the fit weighs each figure by it")
        return FigureSpec(name, float(y))
    return FigureSpec(name, float(y), **_uncertainty(where, label, value["uncertainty"], scale))


def _parse_figures(where: str, raw: dict) -> tuple[tuple, tuple]:
    fit_t, held_t = raw.get("fitted") or {}, raw.get("held_out") or {}
    if not fit_t:
        raise _fail(where, "[fitted] is required and must name at least one measured figure")
    both = [k for k in fit_t if k in held_t]
    if both:
        raise _fail(where, f"figure {both[0]!r} is in [fitted] and in [held_out]: a held-out figure is "
                           "predicted, never used in the fit; keep it in one of them")
    fitted = tuple(_parse_figure(where, "fitted", k, v, True) for k, v in fit_t.items())
    held = tuple(_parse_figure(where, "held_out", k, v, False) for k, v in held_t.items())
    return fitted, held


# ------------------------------------------------------------------ planning


def plan_design_units(spec: IdentifySpec) -> np.ndarray:
    """The design's unit coordinates: a Latin hypercube of ``spec.runs`` points, seeded by ``spec.seed``.

    Parameters
    ----------
    spec : IdentifySpec
        The spec.

    Returns
    -------
    (runs, d) ndarray
        Unit coordinates in [0, 1) [-].
    """
    from scipy.stats import qmc

    rng = np.random.default_rng(np.random.SeedSequence((spec.seed, 0x1DE7)))
    return qmc.LatinHypercube(d=len(spec.parameters), seed=rng).random(spec.runs)


def plan_run(spec: IdentifySpec, index: int, unit, role: str, where: str = "spec") -> RunPlan:
    """Run ``index`` at unit coordinates ``unit``: its rig, values and seed.

    Parameters
    ----------
    spec : IdentifySpec
        The spec.
    index : int
        Run number k [-].
    unit : (d,) array_like
        Unit coordinates of the free parameters [-].
    role : {"design", "refine", "held-out"}
        The phase.
    where : str
        Name of the spec in error messages.

    Returns
    -------
    RunPlan
        The run.

    Raises
    ------
    StudyError
        The rig validation refuses the run's values (naming the run and them).
    """
    tables, values = spec.rig_tables, {}
    for p, q in zip(spec.parameters, unit):
        values[p.key] = p.value(float(q))
        tables = _with_value(tables, p.key, values[p.key])
    try:
        full = rig_to_dict(rig_from_dict(tables))
    except RigError as exc:
        shown = ", ".join(f"{k} = {v:g}" for k, v in values.items())
        raise _fail(where, f"run {index} ({shown}) is not a possible rig: {exc}; narrow that range") from None
    figures = spec.fitted + spec.held_out if role == "held-out" else spec.fitted
    return RunPlan(index, sample_seed(spec.seed, index), full, values, tuple(float(q) for q in unit), role,
                   spec.experiments(figures), spec.experiment, spec.keep_frames)


def plan_design(spec: IdentifySpec) -> list[RunPlan]:
    """Every design run of the spec (runs 0 … ``spec.runs`` − 1).

    Parameters
    ----------
    spec : IdentifySpec
        The spec.

    Returns
    -------
    list of RunPlan
        Run k at index k.
    """
    units = plan_design_units(spec)
    return [plan_run(spec, k, units[k], "design") for k in range(spec.runs)]
