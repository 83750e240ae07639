"""Design studies through the twin: design sweeps, tolerance Monte Carlo, sensitivity, propagation.

Modules: :mod:`.spec` (the TOML spec, every draw planned and checked),
:mod:`.outputs` (closed-form design numbers and measured outputs of a draw),
:mod:`.draw` (one draw: render, calibrate, scan, score; resumable),
:mod:`.geometric` (the same chain on the exact stripe, without rendering),
:mod:`.propagation` (first-order analytic propagation by finite differences),
:mod:`.analysis` (distributions, Sobol/Morris indices, ranking, limits, best designs,
Pareto front), :mod:`.run` (the whole job on the dataset engine).
"""

from .analysis import analyse_sweep, analyse_tolerance, best_designs, table_rows, tolerance_limit
from .draw import run_draw
from .geometric import GeometricTwin, sheet_field_error
from .propagation import propagate
from .run import StudyResult, run_study
from .spec import DrawPlan, StudySpec, load_study_spec, parse_study_spec, plan_draws

__all__ = [
    "DrawPlan",
    "GeometricTwin",
    "StudyResult",
    "StudySpec",
    "analyse_sweep",
    "analyse_tolerance",
    "best_designs",
    "load_study_spec",
    "parse_study_spec",
    "plan_draws",
    "propagate",
    "run_draw",
    "run_study",
    "sheet_field_error",
    "table_rows",
    "tolerance_limit",
]
