"""Identification: the unknown parameters of one instrument from its own figures, with uncertainty.

Modules: :mod:`.spec` (the TOML spec: base rig, free parameters with priors, the
experiment, fitted and held-out figures; every design run planned and checked),
:mod:`.figures` (the figures by experiment and processing, their statistical
scales), :mod:`.runs` (one twin run: render, measure; resumable),
:mod:`.surrogate` (a Gaussian process per figure with leave-one-out
cross-validation), :mod:`.posterior` (the likelihood, MCMC, ABC, summaries,
predictive intervals), :mod:`.fit` (design runs → posterior and its draws),
:mod:`.job` (the whole job on the dataset engine: ``scheimpflug identify``),
:mod:`.scan` (a twin's unknowns from a real scan's own frames: image-level figures,
the same surrogate and posterior; ``scheimpflug twin build``).
"""

from .figures import FIGURES, FigureDef
from .fit import fit_posterior
from .job import IdentifyResult, identified_rig_text, run_identify, summarise_identification
from .runs import measure_rig, run_one
from .scan import identify_scan
from .spec import IdentifySpec, Parameter, load_identify_spec, parse_identify_spec, plan_design
from .surrogate import GaussianProcess, fit_gp

__all__ = [
    "FIGURES",
    "FigureDef",
    "GaussianProcess",
    "IdentifyResult",
    "IdentifySpec",
    "Parameter",
    "fit_gp",
    "fit_posterior",
    "identified_rig_text",
    "identify_scan",
    "load_identify_spec",
    "measure_rig",
    "parse_identify_spec",
    "plan_design",
    "run_identify",
    "run_one",
    "summarise_identification",
]
