"""Study specs (TOML): a design sweep or a tolerance Monte Carlo, checked before anything runs.

Format (lengths in mm, angles in degrees; examples in ``studies/examples/``)::

    [study]
    seed = 1                  # base seed: draw k's values and seeds derive from (seed, k) only
    draws = 64                # tolerance: Monte Carlo draws allowed (a draw is resumable)
    method = "sobol"          # tolerance: "sobol" (S1 and ST; N·(d + 2) draws, N a power of two)
                              #   or "morris" (screening, r·(d + 1) draws)
    sampling = "grid"         # sweep: "grid" (every combination) or "lhs" (Latin hypercube)
    designs = 16              # sweep with sampling = "lhs": number of designs
    model = "paper"           # calibration model of every draw: paper | general | auto
    metric = "SD_mm"          # the error that ranks: SD_mm | PF_mm | PS_mm | F_mm
    max_error_mm = 0.1        # optional target for the tolerance ranking ("keep it under …")
    noise = "common"          # "common": one noise seed for every draw (the tolerances alone vary);
                              #   "independent": draw k's own seed
    keep_frames = false       # keep every draw's rendered frame folders
    name = "…"                # optional; description = "…"

    [rig]
    preset = "paper"          # or file = "RIG.toml" (relative to the spec file)
    derive = false            # tolerance: true = derive the stage layout, waist and exposure of the
                              #   design (set below) instead of taking the preset's (sweeps always do)
    [rig.set]                 # fixed changes of the rig: the design, the realism the study turns on
    "laser.speckle_contrast" = 1.0
    "twin.speckle_model" = "sensor"   # strings and booleans too, of the rig value's type

    [tolerance]               # rig key = half-width of a uniform deviation around the rig's value,
    "sensor.roll_deg" = 0.2   #   or { normal = SIGMA }
    "stage.axis_tilt_deg" = { normal = 0.05 }

    [sweep]                   # design keys: a list of values or { range = [lo, hi], steps = n }
    "laser.tan_phi" = [0.15, 0.2075, 0.25]
    "lens.focal_length_mm" = { range = [35.0, 75.0], steps = 5 }

    [placement]               # sweep, optional: place every design's sensor to cover near…far
    near_mm = 300.0           #   (distances along the sheet from the laser, as `design --near-mm`)
    far_mm = 600.0
    solve = "tan_phi"         #   the key solved: "tan_phi" or "scheimpflug_distance_mm"

    [artefacts]               # what every draw scans (VDI/VDE 2634-2 artefacts, sim.acceptance)
    kinds = ["sphere", "plane", "ball-bar"]   # [] = closed forms only (sweep)
    binning = 1               # k × k binned sensor (same geometry; the closed forms are full-size)
    positions = "quick"       # "quick" (2 spheres, 1 ball bar, 1 plane) or "full" (10, 7, 6)
    frames = 9                # frames per sphere crossing / plane scan (default 9 quick, 21 full)
    material = "cardboard"    # the artefacts' surface: cardboard (diffuse) | metal | knurled-metal | tape
    spp = 32                  # optional: laser samples per lit row
    exclude_fraction = 0.003  # the guideline's outlier exclusion (0 = none)
    part = "bracket.stl"      # optional: a user part (preset name or mesh/scene file) scanned on the
    part_step_deg = 6.0       #   rotary stage too and scored against its mesh (part_rms_mm)

In a sweep every design's stage layout, laser waist and exposure (the keys of
:data:`scheimpflug.model.rig.DERIVED_KEYS`) are derived from its own working
volume (:mod:`scheimpflug.model.plan`), for its binned sensor, unless
``[rig.set]`` or ``[sweep]`` gives them; in a tolerance study they are the
rig's (derived for the design when ``[rig] derive = true`` or when the rig file
leaves them out) and pinned: the as-built copies share one stage layout and
one calibration plan.  A tolerance applies to a continuous rig key that exists; a key whose value
must stay ≥ 0 and is 0 in the rig (``stage.axis_tilt_deg``, ``stage.runout_um``
…) is drawn as a magnitude ``|x|``.  Every unknown table or key, a tolerance on
a key the rig does not have (the message names it and the closest keys), a
non-positive width, a sweep that is empty or reversed, a design (or a drawn
rig) that the rig validation refuses, is one :class:`StudyError` naming it.

Seeds.  The tolerance draws are rows of one unit sample
(:func:`scheimpflug.sensitivity.unit_sample`, seeded by ``seed``); a Latin
hypercube sweep is seeded by ``seed``.  Draw k's render seed is
``sample_seed(seed, k)`` (``noise = "independent"``) or ``sample_seed(seed, 0)``
for every draw (``"common"``, the default: common random numbers, so that the
differences between draws are the tolerances' and the sensitivity indices are
not blurred by noise).  Nothing depends on the number of workers.
"""

from __future__ import annotations

import difflib
import hashlib
import itertools
import json
import math
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scheimpflug.errors import RenderError, RigError, ScheimpflugError, StudyError
from scheimpflug.model.binning import binned_rig
from scheimpflug.model.design import inverse_design
from scheimpflug.model.plan import calibration_plan
from scheimpflug.model.rig import DERIVED_KEYS, PRESETS, preset_tables, read_toml, rig_from_dict, rig_to_dict
from scheimpflug.sensitivity import METHODS, deviation_from_unit, unit_sample

from ..dataset.spec import sample_seed

__all__ = [
    "ARTEFACT_KINDS",
    "MAX_DRAWS",
    "METRICS",
    "METRIC_NEEDS",
    "ArtefactSettings",
    "DrawPlan",
    "Placement",
    "StudySpec",
    "SweepAxis",
    "Tolerance",
    "calibration_options",
    "check_constraints",
    "load_study_spec",
    "parse_study_spec",
    "plan_draws",
]

#: Artefact kinds as written in a spec → the acceptance plan's kinds.
ARTEFACT_KINDS = {"sphere": "sphere", "ball-bar": "ball_bar", "plane": "plane"}
#: Errors a study can rank and constrain, with their plain names.
METRICS = {"SD_mm": "sphere-spacing error", "PF_mm": "probing error (form)",
           "PS_mm": "probing error (size)", "F_mm": "flatness error",
           "part_rms_mm": "RMS distance of the user part's points from its mesh"}
_MATERIALS = ("cardboard", "knurled-metal", "metal", "tape")
_TOP = {"study", "rig", "tolerance", "sweep", "placement", "artefacts"}
_STUDY_KEYS = {"seed", "draws", "method", "sampling", "designs", "model", "metric", "max_error_mm", "noise",
               "keep_frames", "name", "description"}
_ARTEFACT_KEYS = {"kinds", "binning", "positions", "frames", "material", "spp", "exclude_fraction", "part",
                  "part_step_deg"}
_SOLVE = ("tan_phi", "scheimpflug_distance_mm")
#: Most draws (tolerance study) or designs (sweep) one study may plan: a rendered draw takes tens of
#: seconds to minutes (10 000 of them: days of CPU), planning one design ≈ 7 ms [-].
MAX_DRAWS = 10_000
#: Most frames per sphere crossing / plane scan (the guideline's full plan uses 21) [-].
MAX_FRAMES_PER_SCAN = 1000
#: Most frames of the user part's turn (``round(360 / part_step_deg)``; ``render``'s --yes threshold) [-].
MAX_PART_FRAMES = 10_000
#: What measures each metric: an artefact kind of the plan, or the user part (``artefacts.part``).
METRIC_NEEDS = {"SD_mm": "ball_bar", "PF_mm": "sphere", "PS_mm": "sphere", "F_mm": "plane", "part_rms_mm": "part"}
_NEEDS_TEXT = {"ball_bar": ("the ball bar", 'add "ball-bar" to artefacts.kinds'),
               "sphere": ("the sphere", 'add "sphere" to artefacts.kinds'),
               "plane": ("the plane", 'add "plane" to artefacts.kinds'),
               "part": ("a user part", "set artefacts.part (and at least one artefact kind)")}


def _fail(where: str, msg: str) -> StudyError:
    return StudyError(f"{where}: {msg}")


def _num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


@dataclass(frozen=True)
class Tolerance:
    """One toleranced rig key.

    Parameters
    ----------
    key : str
        ``"table.key"`` of the rig.
    kind : {"uniform", "normal"}
        Distribution of the deviation.
    width : float
        Half-width of the uniform deviation, or σ of the normal one, in the key's unit.
    magnitude : bool
        Drawn as ``|x|`` (a key that must stay ≥ 0 and is 0 in the rig).
    """

    key: str
    kind: str
    width: float
    magnitude: bool = False

    @property
    def sigma(self) -> float:
        """Standard deviation of the signed deviation: a/√3 (uniform) or σ (normal) [key unit]."""
        return self.width / math.sqrt(3.0) if self.kind == "uniform" else self.width

    def describe(self) -> str:
        """``± a (uniform)`` or ``σ = s (normal)``, with ``|x|`` for a magnitude [-].

        Returns
        -------
        str
            Short text for reports.
        """
        text = f"±{self.width:g} uniform" if self.kind == "uniform" else f"σ = {self.width:g} normal"
        return text + (", drawn as |x|" if self.magnitude else "")


@dataclass(frozen=True)
class SweepAxis:
    """One swept design key.

    Parameters
    ----------
    key : str
        ``"table.key"`` of the rig.
    values : tuple of float
        The grid values (explicit list, or ``steps`` points over the range).
    bounds : tuple of float or None
        ``(lo, hi)`` of a range (Latin hypercube draws in it); None for an explicit list.
    integer : bool
        The key is an integer (values rounded).
    """

    key: str
    values: tuple
    bounds: tuple | None
    integer: bool

    def at(self, q: float):
        """The value at unit coordinate q ∈ [0, 1) (Latin hypercube): in the range, or a list entry.

        Parameters
        ----------
        q : float
            Unit coordinate [-].

        Returns
        -------
        float or int
            The design value.
        """
        if self.bounds is None:
            return self.values[min(int(q * len(self.values)), len(self.values) - 1)]
        x = self.bounds[0] + q * (self.bounds[1] - self.bounds[0])
        return int(round(x)) if self.integer else float(x)


@dataclass(frozen=True)
class Placement:
    """Place every design's sensor (and one free key) so that it covers near…far (inverse design).

    Parameters
    ----------
    near_mm, far_mm : float
        Wanted range, along the sheet from the laser / Scheimpflug line [mm].
    solve : {"tan_phi", "scheimpflug_distance_mm"}
        The laser key solved for; the other is the design's.
    """

    near_mm: float
    far_mm: float
    solve: str


@dataclass(frozen=True)
class ArtefactSettings:
    """What every draw scans and how (the ``[artefacts]`` table).

    Parameters
    ----------
    kinds : tuple of str
        Acceptance-plan kinds (``sphere``, ``ball_bar``, ``plane``); empty = closed forms only.
    binning : int
        k × k binned sensor [-].
    quick : bool
        The reduced plan (2 spheres, 1 ball bar, 1 plane) instead of the guideline's.
    frames : int or None
        Frames per crossing (None = the plan's default).
    material : str
        The artefacts' material tag.
    spp : int or None
        Laser samples per lit row (None = the renderer's default).
    exclude_fraction : float
        Outlier fraction excluded per measurement [-].
    part : str or None
        A user part scanned too (preset name or resolved file path), None = none.
    part_step_deg : float
        Its rotary step [deg].
    """

    kinds: tuple = ("sphere", "ball_bar", "plane")
    binning: int = 1
    quick: bool = True
    frames: int | None = None
    material: str = "cardboard"
    spp: int | None = None
    exclude_fraction: float = 0.003
    part: str | None = None
    part_step_deg: float = 6.0


@dataclass(frozen=True)
class StudySpec:
    """A parsed, validated study spec (format in the module docstring).

    Parameters
    ----------
    raw : dict
        The spec as read (JSON-ready): a study folder's identity.
    folder : Path
        Folder of the spec file (relative paths resolve against it).
    kind : {"sweep", "tolerance"}
        What the spec asks for.
    name, description : str
        For the report.
    seed : int
        Base seed [-].
    draws : int
        Tolerance: draws allowed; sweep: number of designs [-].
    method : str
        Tolerance: ``sobol`` or ``morris``.
    sampling : str
        Sweep: ``grid`` or ``lhs``.
    model : str
        Calibration model of every draw.
    metric : str
        The error that ranks (a key of :data:`METRICS`).
    max_error_mm : float or None
        Target of the metric [mm].
    noise : {"common", "independent"}
        Render seeds of the draws.
    keep_frames : bool
        Keep the rendered frame folders.
    rig_tables : dict
        The base rig's tables as given (preset or file, ``[rig.set]`` applied): keys left out
        stay out, so that rig-derived defaults are derived per design.
    rig_source : str
        ``"preset:NAME"`` or ``"file:PATH"``.
    tolerances : tuple of Tolerance
        Tolerance study: the toleranced keys.
    sweep : tuple of SweepAxis
        Sweep: the swept keys.
    placement : Placement or None
        Sweep: sensor placement per design.
    artefacts : ArtefactSettings
        What every draw scans.
    """

    raw: dict
    folder: Path
    kind: str
    name: str
    description: str
    seed: int
    draws: int
    method: str
    sampling: str
    model: str
    metric: str
    max_error_mm: float | None
    noise: str
    keep_frames: bool
    rig_tables: dict
    rig_source: str
    tolerances: tuple = ()
    sweep: tuple = ()
    placement: Placement | None = None
    artefacts: ArtefactSettings = field(default_factory=ArtefactSettings)

    @property
    def keys(self) -> list[str]:
        """The toleranced or swept keys, in spec order."""
        return [t.key for t in (self.tolerances or self.sweep)]

    def sha256(self) -> str:
        """SHA-256 of the canonical JSON of :attr:`raw` (the spec's identity).

        Returns
        -------
        str
            64 hex digits.
        """
        return hashlib.sha256(json.dumps(self.raw, sort_keys=True).encode()).hexdigest()

    def input_files(self) -> list[Path]:
        """Files the spec refers to (the rig file, the user part), resolved, existing only.

        Returns
        -------
        list of Path
            The rig file and the part's file, if any.
        """
        names = [self.rig_source[5:]] if self.rig_source.startswith("file:") else []
        if self.artefacts.part and Path(self.artefacts.part).suffix:
            names.append(self.artefacts.part)
        return [p for p in (_resolve(self.folder, n) for n in names) if p.is_file()]

    def base_rig(self):
        """The study's base rig (the nominal design of a tolerance study).

        Returns
        -------
        Rig
            Built from :attr:`rig_tables`.
        """
        return rig_from_dict(self.rig_tables)


@dataclass(frozen=True)
class DrawPlan:
    """What draw k runs: everything a worker needs to run it alone.

    Parameters
    ----------
    index : int
        Draw (design) number k [-].
    seed : int
        Render seed [-].
    rig : dict
        The draw's full-size rig as nested tables.
    nominal : dict
        The nominal rig (tolerance study: the design; sweep: the draw's own rig).
    values : dict
        ``"table.key"`` → the draw's value of every toleranced / swept key (and solved keys).
    deviations : dict
        Tolerance study: ``"table.key"`` → deviation from the nominal value.
    unit : tuple of float
        The draw's unit coordinates (tolerance study) [-].
    status : str
        "" (runnable) or why the design cannot be placed (a row of the table, not an error).
    artefacts : ArtefactSettings
        What to scan.
    model : str
        Calibration model.
    keep_frames : bool
        Keep the frame folders.
    calibration : dict or None
        Calibration scenario options pinned to the design (tolerance study), None = the draw's
        own calibration plan (sweep).
    """

    index: int
    seed: int
    rig: dict
    nominal: dict
    values: dict
    deviations: dict
    unit: tuple
    status: str
    artefacts: ArtefactSettings
    model: str
    keep_frames: bool
    calibration: dict | None = None


# ------------------------------------------------------------------ parsing


def _resolve(folder: Path, name: str) -> Path:
    p = Path(os.path.expanduser(name))
    return p if p.is_absolute() else (folder / p).resolve()


def load_study_spec(path: str | os.PathLike, kind: str) -> StudySpec:
    """Read and validate a study spec file.

    Parameters
    ----------
    path : path
        The TOML spec.
    kind : {"sweep", "tolerance"}
        The command it is for.

    Returns
    -------
    StudySpec
        The validated spec.

    Raises
    ------
    StudyError
        A missing or unreadable file, invalid TOML, or anything :func:`parse_study_spec` refuses.
    """
    p = Path(path)
    raw = read_toml(p, "spec file", StudyError)
    return parse_study_spec(raw, kind, folder=p.resolve().parent, where=str(p), default_name=p.stem)


def parse_study_spec(raw: dict, kind: str, folder: str | os.PathLike = ".", where: str = "spec",
                     default_name: str = "study") -> StudySpec:
    """Validate a study spec given as nested tables.

    Parameters
    ----------
    raw : dict
        The spec's tables.
    kind : {"sweep", "tolerance"}
        The command it is for: a sweep needs ``[sweep]``, a tolerance study ``[tolerance]``.
    folder : path
        Folder that relative paths resolve against.
    where : str
        Name of the spec in error messages.
    default_name : str
        Study name when ``[study] name`` is not given.

    Returns
    -------
    StudySpec
        The validated spec (every draw is planned by :func:`plan_draws`).

    Raises
    ------
    StudyError
        An unknown table or key, a tolerance on a key the rig does not have, a bad value,
        a sweep that is empty or reversed.
    """
    if kind not in ("sweep", "tolerance"):
        raise ValueError(f"unknown study kind {kind!r}")
    _known(where, "the spec", raw, _TOP)
    for table in _TOP & set(raw):
        if not isinstance(raw[table], dict):
            raise _fail(where, f"[{table}] must be a table")
    other = "sweep" if kind == "tolerance" else "tolerance"
    if other in raw:
        raise _fail(where, f"[{other}] belongs in a {other} spec; `study {kind}` needs [{kind}]")
    if not raw.get(kind):
        raise _fail(where, f"[{kind}] is required and must name at least one rig key")
    if "placement" in raw and kind == "tolerance":
        raise _fail(where, "[placement] belongs in a sweep spec")
    st = raw.get("study", {})
    _known(where, "[study]", st, _STUDY_KEYS)
    folder = Path(folder)
    _check_overrides(where, raw, kind)
    tables, source = _parse_rig(where, folder, raw.get("rig", {}))
    common = _parse_study_table(where, st, kind)
    artefacts = _parse_artefacts(where, raw.get("artefacts", {}), folder)
    try:
        binned_rig(rig_from_dict(tables), artefacts.binning)
    except (RigError, ValueError) as exc:
        raise _fail(where, f"artefacts.binning = {artefacts.binning}: {exc}") from None
    _check_metric(where, common["metric"], "metric" in st, common["max_error_mm"], artefacts, kind)
    spec = StudySpec(raw=json.loads(json.dumps(raw)), folder=folder, kind=kind,
                     name=str(st.get("name", default_name)), description=str(st.get("description", "")),
                     rig_tables=tables, rig_source=source, artefacts=artefacts, **common)
    if kind == "tolerance":
        return _with_tolerances(where, spec, raw["tolerance"])
    return _with_sweep(where, spec, raw["sweep"], raw.get("placement"))


def _check_overrides(where: str, raw: dict, kind: str) -> None:
    """A key that ``[rig.set]`` fixes and a sweep also sets (swept, or solved by the placement) is refused.

    In a tolerance study a ``[rig.set]`` value is the nominal the tolerance is drawn around: both together
    are meaningful and kept.
    """
    given = raw.get("rig", {}).get("set", {})
    if kind != "sweep" or not isinstance(given, dict):
        return
    swept = raw.get("sweep") or {}
    for key in swept:
        if key in given:
            raise _fail(where, f"{key!r} is given in [rig.set] and in [sweep]: the sweep would override "
                               "[rig.set]; give it in one of them")
    placement = raw.get("placement")
    if isinstance(placement, dict):
        solve = placement.get("solve", "tan_phi")
        for key in (f"laser.{solve}", "sensor.hinge_column"):
            if key in given:
                raise _fail(where, f"{key!r} is given in [rig.set] but [placement] solves it for every design "
                                   "(it would be overridden): remove it from [rig.set]")


def _kinds_text(a: ArtefactSettings) -> str:
    names = {v: k for k, v in ARTEFACT_KINDS.items()}
    return "[" + ", ".join(f'"{names[k]}"' for k in a.kinds) + "]"


def _measurable(a: ArtefactSettings) -> list[str]:
    return [m for m, need in METRIC_NEEDS.items() if (need in a.kinds) or (need == "part" and a.part and a.kinds)]


def _check_metric(where: str, metric: str, explicit: bool, max_error_mm, a: ArtefactSettings, kind: str) -> None:
    """The artefacts measure the metric (and so every limit on it): checked before anything is planned."""
    if a.part and not a.kinds:
        raise _fail(where, "artefacts.part: the part is scanned with each draw's calibration, which needs at "
                           "least one artefact kind; artefacts.kinds = [] scans nothing")
    if not a.kinds:             # a tolerance study refuses it (_with_tolerances); a sweep: closed forms only
        if kind == "sweep" and (explicit or max_error_mm is not None):
            what = f"study.metric = {metric!r}:" if explicit else f"study.max_error_mm limits the {metric}:"
            raise _fail(where, f"{what} artefacts.kinds = [] measures nothing (closed forms only, ranked by "
                               "the distance resolution); add the artefact it needs or remove it")
        return
    need = METRIC_NEEDS[metric]
    if need in a.kinds or (need == "part" and a.part):
        return
    thing, fix = _NEEDS_TEXT[need]
    other = ", ".join(_measurable(a)) or "none"
    default = "" if explicit else ", the default"
    raise _fail(where, f"study.metric = {metric!r} ({METRICS[metric]}{default}) needs {thing}, which "
                       f"artefacts.kinds = {_kinds_text(a)} does not scan: {fix}, or choose a metric they "
                       f"measure ({other})")


def check_constraints(spec: StudySpec, near_mm: float | None = None, far_mm: float | None = None,
                      max_error_mm: float | None = None) -> None:
    """Refuse a constraint whose figure the study cannot measure, before anything runs.

    ``near_mm`` and ``far_mm`` are closed forms of every design (always known); ``max_error_mm``
    limits the metric, which a sweep without artefacts does not measure.

    Parameters
    ----------
    spec : StudySpec
        The study.
    near_mm, far_mm, max_error_mm : float, optional
        The constraints of ``study sweep`` [mm].

    Raises
    ------
    StudyError
        ``max_error_mm`` given for a sweep without artefacts.
    """
    if max_error_mm is not None and not spec.artefacts.kinds:
        raise StudyError(f"--max-error-mm {max_error_mm:g} limits the {spec.metric}, which artefacts.kinds = [] "
                         "does not measure (closed forms only): add the artefact it needs to the spec")


def _known(where: str, table: str, data: dict, known: set) -> None:
    unknown = sorted(set(data) - known)
    if unknown:
        raise _fail(where, f"unknown key {unknown[0]!r} in {table} (known: {', '.join(sorted(known))})")


def _choice(where: str, key: str, value, choices) -> str:
    if value not in choices:
        raise _fail(where, f"{key} = {value!r}: unknown (known: {', '.join(choices)})")
    return value


def _integer(where: str, key: str, value, minimum: int) -> int:
    if not isinstance(value, int) or isinstance(value, bool) or value < minimum:
        raise _fail(where, f"{key} = {value!r}: must be an integer >= {minimum}")
    return value


def _at_most(where: str, key: str, value: int, limit: int, noun: str, hint: str = "split the study") -> int:
    if value > limit:
        raise _fail(where, f"{key} = {value:,}: more than the limit of {limit:,} {noun} "
                           f"(sized before anything is planned; {hint})")
    return value


def _parse_study_table(where: str, st: dict, kind: str) -> dict:
    seed = _integer(where, "study.seed", st.get("seed", 0), 0)
    if kind == "tolerance":
        if "draws" not in st:
            raise _fail(where, "study.draws is required (the Monte Carlo draws allowed)")
        draws = _at_most(where, "study.draws", _integer(where, "study.draws", st["draws"], 1), MAX_DRAWS,
                         "draws per study")
    else:
        draws = _at_most(where, "study.designs", _integer(where, "study.designs", st.get("designs", 1), 1),
                         MAX_DRAWS, "designs per study")
    for key, only in (("method", "tolerance"), ("draws", "tolerance"), ("sampling", "sweep"),
                      ("designs", "sweep")):
        if key in st and kind != only:
            raise _fail(where, f"study.{key} belongs in a {only} spec")
    max_err = st.get("max_error_mm")
    if max_err is not None and not (_num(max_err) and max_err > 0):
        raise _fail(where, f"study.max_error_mm = {max_err!r}: must be a number > 0")
    keep = st.get("keep_frames", False)
    if not isinstance(keep, bool):
        raise _fail(where, f"study.keep_frames = {keep!r}: must be true or false")
    return {"seed": seed, "draws": draws,
            "method": _choice(where, "study.method", st.get("method", "sobol"), METHODS),
            "sampling": _choice(where, "study.sampling", st.get("sampling", "grid"), ("grid", "lhs")),
            "model": _choice(where, "study.model", st.get("model", "paper"), ("paper", "general", "auto")),
            "metric": _choice(where, "study.metric", st.get("metric", "SD_mm"), tuple(METRICS)),
            "max_error_mm": None if max_err is None else float(max_err),
            "noise": _choice(where, "study.noise", st.get("noise", "common"), ("common", "independent")),
            "keep_frames": keep}


def _parse_rig(where: str, folder: Path, table: dict) -> tuple[dict, str]:
    _known(where, "[rig]", table, {"preset", "file", "set", "derive"})
    if not isinstance(table.get("derive", False), bool):
        raise _fail(where, f"rig.derive = {table['derive']!r}: must be true or false")
    if "preset" in table and "file" in table:
        raise _fail(where, "[rig]: give either preset or file, not both")
    if "file" in table:
        name = str(table["file"])
        path = _resolve(folder, name)
        try:
            tables = tomllib.loads(path.read_bytes().decode("utf-8"))
        except FileNotFoundError:
            raise _fail(where, f"rig.file = {name!r} does not exist") from None
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
            raise _fail(where, f"rig.file = {name!r} cannot be read: {exc}") from None
        source = f"file:{name}"
    else:
        preset = table.get("preset", "paper")
        if preset not in PRESETS:
            raise _fail(where, f"rig.preset = {preset!r}: unknown (known: {', '.join(PRESETS)})")
        tables, source = preset_tables(preset), f"preset:{preset}"
    _rig_or_fail(where, "[rig]", tables)
    changes = table.get("set", {})
    if not isinstance(changes, dict):
        raise _fail(where, "[rig.set] must be a table of \"table.key\" = value")
    for key, value in changes.items():
        current = _rig_key(where, "rig.set", key, tables, numeric=False)
        if _num(current) != _num(value) or (not _num(current) and type(value) is not type(current)):
            raise _fail(where, f"rig.set: {key!r} = {value!r}: the rig's value is {current!r} "
                               f"({type(current).__name__})")
        tables = _with_value(tables, key, value)
        _rig_or_fail(where, "[rig.set]", tables)
    return tables, source


def _rig_or_fail(where: str, what: str, tables: dict):
    try:
        return rig_from_dict(tables)
    except RigError as exc:
        raise _fail(where, f"{what}: {exc}") from None


def _all_keys(tables: dict) -> dict:
    """Every ``table.key`` of the rig (built from ``tables``) with its value."""
    full = rig_to_dict(rig_from_dict(tables))
    return {f"{t}.{k}": v for t, kv in full.items() for k, v in kv.items()}


def _rig_key(where: str, section: str, key, tables: dict, numeric: bool = True):
    """The rig's value of ``key`` (a number unless ``numeric``); an error for an unknown key."""
    known = _all_keys(tables)
    if key not in known:
        close = difflib.get_close_matches(str(key), list(known), n=3, cutoff=0.6)
        hint = f"; did you mean {', '.join(repr(c) for c in close)}?" if close else \
            f"; the rig's keys are {', '.join(sorted(known))}"
        raise _fail(where, f"{section}: {key!r} is not a key of this rig (\"table.key\", e.g. "
                           f"\"sensor.roll_deg\"){hint}")
    if numeric and not _num(known[key]):
        raise _fail(where, f"{section}: {key!r} is not a number in this rig")
    return known[key]


def _with_value(tables: dict, key: str, value) -> dict:
    out = json.loads(json.dumps(tables))
    tbl, _, leaf = key.partition(".")
    out.setdefault(tbl, {})[leaf] = value
    return out


def _parse_part(where: str, table: dict, folder: Path) -> tuple[str | None, float]:
    from scenes import PART_NAMES

    part, step = table.get("part"), table.get("part_step_deg", 6.0)
    if not (_num(step) and 0 < step <= 90):
        raise _fail(where, f"artefacts.part_step_deg = {step!r}: must be in (0, 90]")
    if round(360.0 / step) > MAX_PART_FRAMES:
        raise _fail(where, f"artefacts.part_step_deg = {step!r}: {round(360.0 / step):,} frames per turn, more "
                           f"than the limit of {MAX_PART_FRAMES:,} (a step >= {360.0 / MAX_PART_FRAMES:g}°)")
    if part is None:
        return None, float(step)
    if not isinstance(part, str) or not part:
        raise _fail(where, f"artefacts.part = {part!r}: a preset name or a mesh / scene file")
    if Path(part).suffix:
        path = _resolve(folder, part)
        if not path.is_file():
            raise _fail(where, f"artefacts.part = {part!r}: no such file ({str(path)!r})")
        return str(path), float(step)
    if part not in PART_NAMES:
        raise _fail(where, f"artefacts.part = {part!r}: unknown part (known: {', '.join(PART_NAMES)})")
    return part, float(step)


def _parse_artefacts(where: str, table: dict, folder: Path) -> ArtefactSettings:
    _known(where, "[artefacts]", table, _ARTEFACT_KEYS)
    kinds = table.get("kinds", ["sphere", "plane", "ball-bar"])
    if not isinstance(kinds, list) or len(set(map(str, kinds))) != len(kinds):
        raise _fail(where, f"artefacts.kinds = {kinds!r}: must be a list of distinct kinds")
    for k in kinds:
        _choice(where, "artefacts.kinds", k, tuple(ARTEFACT_KINDS))
    positions = _choice(where, "artefacts.positions", table.get("positions", "quick"), ("quick", "full"))
    frames = table.get("frames")
    spp = table.get("spp")
    excl = table.get("exclude_fraction", 0.003)
    if not (_num(excl) and 0 <= excl < 0.5):
        raise _fail(where, f"artefacts.exclude_fraction = {excl!r}: must be in [0, 0.5)")
    order = [k for k in ("sphere", "ball-bar", "plane") if k in kinds]
    return ArtefactSettings(
        kinds=tuple(ARTEFACT_KINDS[k] for k in order),
        binning=_integer(where, "artefacts.binning", table.get("binning", 1), 1),
        quick=positions == "quick",
        frames=None if frames is None else _at_most(where, "artefacts.frames", _integer(
            where, "artefacts.frames", frames, 3), MAX_FRAMES_PER_SCAN, "frames per scan", "the guideline uses 21"),
        material=_choice(where, "artefacts.material", table.get("material", "cardboard"), _MATERIALS),
        spp=None if spp is None else _integer(where, "artefacts.spp", spp, 1),
        exclude_fraction=float(excl), **dict(zip(("part", "part_step_deg"), _parse_part(where, table, folder))))


# ------------------------------------------------------------------ tolerances


def _parse_tolerance(where: str, key: str, value, base: float) -> Tolerance:
    name = f"tolerance.{key!r}"
    if _num(value):
        if not value > 0:
            raise _fail(where, f"{name} = {value!r}: a half-width must be > 0")
        return Tolerance(key, "uniform", float(value))
    if isinstance(value, dict) and set(value) == {"normal"}:
        sigma = value["normal"]
        if not (_num(sigma) and sigma > 0):
            raise _fail(where, f"{name} = {value!r}: normal needs a sigma > 0 ({{ normal = SIGMA }})")
        return Tolerance(key, "normal", float(sigma))
    raise _fail(where, f"{name} = {value!r}: give a half-width (a number > 0) or {{ normal = SIGMA }}")


def _is_magnitude(tables: dict, key: str, base: float, width: float) -> bool:
    """A key at 0 that must stay ≥ 0: a small negative value is refused, a positive one is not."""
    if base != 0:
        return False
    try:
        rig_from_dict(_with_value(tables, key, -1e-3 * width))
    except RigError:
        try:
            rig_from_dict(_with_value(tables, key, 1e-3 * width))
        except RigError:
            return False
        return True
    return False


def _pinned(tables: dict, binning: int) -> dict:
    """Every key given: derived keys take the values the rule gives the *binned* design.

    A tolerance study measures as-built copies of one design: its stage layout, waist and
    exposure must not move with the drawn keys.  They are pinned to what the rig-derived
    defaults give the design's binned sensor (the pixels the pipeline reads; the exposure
    scaled back to full size), which is what an unpinned binned run would use.
    """
    rig = rig_from_dict(tables)
    full = rig_to_dict(rig)
    if binning > 1 and rig.derived:
        rb = rig_to_dict(binned_rig(rig, binning))
        for key in rig.derived:
            tbl, _, leaf = key.partition(".")
            full[tbl][leaf] = rb[tbl][leaf] * (binning ** 2 if key == "sensor.exposure_ms" else 1)
    return full


def calibration_options(rig_b) -> dict:
    """The calibration scenario of a (binned) design, as scenario options that pin it.

    Parameters
    ----------
    rig_b : Rig
        The design as the draws read it (binned).

    Returns
    -------
    dict
        ``steps``, ``step_mm``, ``start_mm``, ``plate_height_mm`` of
        :func:`scheimpflug.model.plan.calibration_plan`.
    """
    p = calibration_plan(rig_b)
    return {"steps": int(p.steps), "step_mm": float(p.step_mm), "start_mm": float(p.start_mm),
            "plate_height_mm": float(p.plate_height_mm)}


def _with_tolerances(where: str, spec: StudySpec, table: dict) -> StudySpec:
    if not spec.artefacts.kinds:
        raise _fail(where, "artefacts.kinds = []: a tolerance study measures at least one artefact kind")
    if spec.raw.get("rig", {}).get("derive", False):
        spec = _replace(spec, rig_tables=_derived_per_design(spec, ()))
    nominal = _pinned(spec.rig_tables, spec.artefacts.binning)     # the design is one rig
    tols = []
    for key, value in table.items():
        base = _rig_key(where, "[tolerance]", key, spec.rig_tables)
        if isinstance(base, int):
            raise _fail(where, f"tolerance.{key!r}: an integer key cannot be toleranced")
        tol = _parse_tolerance(where, key, value, base)
        tols.append(Tolerance(tol.key, tol.kind, tol.width, _is_magnitude(nominal, key, base, tol.width)))
    try:
        unit_sample(spec.method, len(tols), spec.draws, spec.seed)
    except ValueError as exc:
        raise _fail(where, f"study.{exc}") from None
    spec = _replace(spec, tolerances=tuple(tols), rig_tables=nominal)
    plan_draws(spec, where=where)       # every drawn rig valid, or one error naming the draw
    return spec


def _replace(spec: StudySpec, **changes) -> StudySpec:
    from dataclasses import replace

    return replace(spec, **changes)


# ------------------------------------------------------------------ sweeps


def _parse_axis(where: str, key: str, value, base) -> SweepAxis:
    name = f"sweep.{key!r}"
    integer = isinstance(base, int)
    if isinstance(value, list):
        if not value or not all(_num(v) for v in value):
            raise _fail(where, f"{name} = {value!r}: a list of values must hold at least one finite number")
        _at_most(where, f"{name}: the number of values", len(value), MAX_DRAWS, "designs per study")
        if integer and not all(float(v).is_integer() for v in value):
            raise _fail(where, f"{name} = {value!r}: an integer key needs integer values")
        vals = tuple(int(v) if integer else float(v) for v in value)
        return SweepAxis(key, vals, None, integer)
    if isinstance(value, dict) and "range" in value and set(value) <= {"range", "steps"}:
        rng = value["range"]
        if not (isinstance(rng, list) and len(rng) == 2 and all(_num(v) for v in rng)):
            raise _fail(where, f"{name}: range must be [lo, hi] with two finite numbers")
        if not rng[0] < rng[1]:
            raise _fail(where, f"{name}: the range {rng!r} is {'empty' if rng[0] == rng[1] else 'reversed'} "
                               "(need lo < hi; a list fixes values)")
        steps = _at_most(where, f"{name}.steps", _integer(where, f"{name}.steps", value.get("steps", 3), 2),
                         MAX_DRAWS, "designs per study")
        vals = np.linspace(float(rng[0]), float(rng[1]), steps)
        vals = tuple(int(round(v)) for v in vals) if integer else tuple(float(v) for v in vals)
        return SweepAxis(key, vals, (float(rng[0]), float(rng[1])), integer)
    raise _fail(where, f"{name} = {value!r}: give a list of values or {{ range = [lo, hi], steps = n }}")


def _parse_placement(where: str, table, swept: list[str]) -> Placement | None:
    if table is None:
        return None
    _known(where, "[placement]", table, {"near_mm", "far_mm", "solve"})
    near, far = table.get("near_mm"), table.get("far_mm")
    if not (_num(near) and _num(far) and 0 < near < far):
        raise _fail(where, f"placement: need 0 < near_mm < far_mm, got near_mm = {near!r}, far_mm = {far!r}")
    solve = _choice(where, "placement.solve", table.get("solve", "tan_phi"), _SOLVE)
    for key in (f"laser.{solve}", "sensor.hinge_column"):
        if key in swept:
            raise _fail(where, f"sweep.{key!r}: [placement] solves {key} for every design; it cannot also be swept")
    return Placement(float(near), float(far), solve)


def _derived_per_design(spec: StudySpec, swept) -> dict:
    """The base tables without the rig-derived keys that neither [rig.set] nor [sweep] gives.

    Sweeps always derive them; a tolerance study when ``[rig] derive = true``.
    """
    given = set(spec.raw.get("rig", {}).get("set", {})) | set(swept)
    out = json.loads(json.dumps(spec.rig_tables))
    for key in DERIVED_KEYS:
        tbl, _, leaf = key.partition(".")
        if key not in given:
            out.get(tbl, {}).pop(leaf, None)
    return out


def _grid_size(where: str, table: dict) -> None:
    """The number of grid designs from the steps alone (before any value is made): refused above the limit."""
    sizes = [len(v) if isinstance(v, list) else v.get("steps", 3) for v in table.values()
             if isinstance(v, list) or (isinstance(v, dict) and isinstance(v.get("steps", 3), int))]
    total = math.prod(sizes)
    if len(sizes) > 1 and total > MAX_DRAWS:
        raise _fail(where, f"sweep: a grid of {' × '.join(f'{n:,}' for n in sizes)} = {total:,} designs, more "
                           f"than the limit of {MAX_DRAWS:,} designs per study: fewer steps, or "
                           "sampling = \"lhs\" with study.designs")


def _with_sweep(where: str, spec: StudySpec, table: dict, placement) -> StudySpec:
    if spec.sampling == "grid":
        _grid_size(where, table)
    spec = _replace(spec, rig_tables=_derived_per_design(spec, table))
    axes = []
    for key, value in table.items():
        base = _rig_key(where, "[sweep]", key, spec.rig_tables)
        axes.append(_parse_axis(where, key, value, base))
    if spec.sampling == "lhs":
        if "designs" not in spec.raw.get("study", {}):
            raise _fail(where, "study.designs is required with sampling = \"lhs\"")
        draws = spec.draws
    else:
        if "designs" in spec.raw.get("study", {}):
            raise _fail(where, "study.designs applies to sampling = \"lhs\" (a grid has every combination)")
        draws = int(np.prod([len(a.values) for a in axes]))
    spec = _replace(spec, sweep=tuple(axes), draws=draws,
                    placement=_parse_placement(where, placement, [a.key for a in axes]))
    plan_draws(spec, where=where)       # every design valid, or one error naming it
    return spec


# ------------------------------------------------------------------ planning


def _design_values(spec: StudySpec) -> list[dict]:
    if spec.sampling == "grid":
        return [dict(zip(spec.keys, combo)) for combo in itertools.product(*(a.values for a in spec.sweep))]
    from scipy.stats import qmc

    q = qmc.LatinHypercube(d=len(spec.sweep), seed=np.random.default_rng(spec.seed)).random(spec.draws)
    return [{a.key: a.at(float(row[i])) for i, a in enumerate(spec.sweep)} for row in q]


def _placed(spec: StudySpec, tables: dict) -> tuple[dict, dict, str]:
    """Tables with the placement's solved key and hinge column; or why it cannot be placed."""
    p = spec.placement
    rig = rig_from_dict(tables)
    kw = {"scheimpflug_distance_mm": rig.laser.scheimpflug_distance_mm} if p.solve == "tan_phi" \
        else {"tan_phi": rig.laser.tan_phi}
    try:
        c = inverse_design(rig.lens.focal_length_mm, rig.sensor.pixel_pitch_um, rig.sensor.columns,
                           p.near_mm, p.far_mm, **kw)
    except RigError as exc:
        return tables, {}, f"cannot be placed to cover {p.near_mm:g}–{p.far_mm:g} mm: {exc}"
    solved = {f"laser.{p.solve}": getattr(c, p.solve), "sensor.hinge_column": c.hinge_column}
    for key, value in solved.items():
        tables = _with_value(tables, key, float(value))
    return tables, solved, ""


def _describe_values(values: dict) -> str:
    return ", ".join(f"{k} = {v:g}" for k, v in values.items())


def _sweep_plans(spec: StudySpec, where: str) -> list[DrawPlan]:
    plans = []
    for k, values in enumerate(_design_values(spec)):
        tables = spec.rig_tables
        for key, value in values.items():
            tables = _with_value(tables, key, value)
        status, solved = "", {}
        try:
            rig_from_dict(tables)
            if spec.placement is not None:
                tables, solved, status = _placed(spec, tables)
            rig_b = binned_rig(rig_from_dict(tables), spec.artefacts.binning)
        except (RigError, ValueError) as exc:
            raise _fail(where, f"design {k} ({_describe_values(values)}) is not a possible rig: {exc}") from None
        _check_spp(where, spec.artefacts, rig_b)
        plans.append(DrawPlan(k, _seed(spec, k), tables, tables, {**values, **solved}, {}, (), status,
                              spec.artefacts, spec.model, spec.keep_frames))
    return plans


def _check_spp(where: str, a: ArtefactSettings, rig_b) -> None:
    """``artefacts.spp`` within the laser pass's memory budget for this (binned) sensor (:mod:`sim.render_limits`)."""
    from ..render_limits import check_laser_samples

    if a.spp is not None:
        try:
            check_laser_samples(a.spp, rig_b.sensor.rows, rig_b.twin.bounces, "artefacts.spp")
        except RenderError as exc:
            raise _fail(where, str(exc)) from None


def _seed(spec: StudySpec, k: int) -> int:
    return sample_seed(spec.seed, 0 if spec.noise == "common" else k)


def _tolerance_plans(spec: StudySpec, where: str) -> list[DrawPlan]:
    q = unit_sample(spec.method, len(spec.tolerances), spec.draws, spec.seed)
    nominal = spec.rig_tables
    known = _all_keys(nominal)
    nominal_b = binned_rig(rig_from_dict(nominal), spec.artefacts.binning)
    _check_spp(where, spec.artefacts, nominal_b)       # rows and bounces are integers: never toleranced
    cal = calibration_options(nominal_b)
    plans = []
    for k, row in enumerate(q):
        tables, values, dev = nominal, {}, {}
        for t, qk in zip(spec.tolerances, row):
            x = float(deviation_from_unit(qk, t.kind, t.width, spec.method))
            x = abs(x) if t.magnitude else x
            dev[t.key], values[t.key] = x, known[t.key] + x
            tables = _with_value(tables, t.key, values[t.key])
        try:
            full = rig_to_dict(rig_from_dict(tables))
        except RigError as exc:
            raise _fail(where, f"draw {k} ({_describe_values(dev)} from the rig's values) is not a possible "
                               f"rig: {exc}; reduce that tolerance") from None
        plans.append(DrawPlan(k, _seed(spec, k), full, nominal, values, dev, tuple(float(v) for v in row), "",
                              spec.artefacts, spec.model, spec.keep_frames, cal))
    return plans


def plan_draws(spec: StudySpec, where: str = "spec") -> list[DrawPlan]:
    """Every draw of the study: its rig, values, seed (module docstring).

    Parameters
    ----------
    spec : StudySpec
        The validated spec.
    where : str
        Name of the spec in error messages.

    Returns
    -------
    list of DrawPlan
        Draw k at index k.

    Raises
    ------
    StudyError
        A design or a drawn rig that the rig validation refuses (naming it, its values and the key).
    """
    try:
        return _tolerance_plans(spec, where) if spec.kind == "tolerance" else _sweep_plans(spec, where)
    except StudyError:
        raise
    except ScheimpflugError as exc:  # pragma: no cover - any other refusal of a rig
        raise _fail(where, str(exc)) from None
