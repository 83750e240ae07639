"""A twin's unknowns from a real scan's own frames: the identification machinery on image-level figures.

The experiment is the scan itself.  The twin (``TWIN_DIR/rig.toml``, ``part.ply``,
``housing.toml`` when there is one) is rendered at the real frames' turntable angles
(``angle_deg`` of the real folder's manifest) — the even-numbered frames of ``fit_frames``
by default, spread over the turn — and its frames go through the same import as the
real ones (a camera chain's colour files → one channel, the real folder's ``channel``)
and the same measurement: the image-level figures per region of
:func:`scheimpflug.compare.figures.folder_figures` (stripe width, peak level, saturated
fraction, halo energy, background level and noise, along-stripe contrast, detection
rate), per frame, then the median over the frames.  The real frames' figures are the
observations.

Unknowns (:func:`default_unknowns`, each a key with a prior; ``unknowns`` replaces them):

* ``laser.power_mw`` — the laser's power × the exposure: the stripe's signal is
  proportional to their product (and to the quantum efficiency), so one of them is free
  and the others stay the rig's; the exposure also scales the room light, which
  ``environment.ambient_irradiance_w_m2`` carries;
* ``laser.waist_um`` (the sheet's waist), ``chain.glare_fraction`` and
  ``chain.glare_scale_um`` (the halo's energy and scale), ``chain.bloom_spill_fraction``
  (blooming), ``chain.black_level_dn`` (the camera's pedestal: a black pixel's value in its
  files), ``laser.speckle_contrast``, ``environment.ambient_irradiance_w_m2``; with
  ``sharpening`` also ``chain.sharpen_amount`` and ``chain.sharpen_sigma_px`` (the camera's unsharp
  mask, :mod:`sim.sharpen`: the dark moat beside a stripe on a dark ground);
* ``material.cardboard_albedo`` (the housing boards and the table, cardboard) and the part's
  material: fields of :class:`sim.materials.MaterialSettings` (or of the part's medium), not rig
  keys — the twin's renderer takes them (``render rotary --twin`` from ``twin.json``); they are
  reported in the result, and written as comments in the identified rig.  The part renders as
  ``part_material`` (:data:`DEFAULT_PART_MATERIAL`, ``white-plastic``: a tag neither the table nor
  the housing has).  A translucent tag is a rough dielectric boundary over a scattering medium
  (:mod:`sim.subsurface`; ``[twin] subsurface`` is set on, in the identified rig too), its
  ``material.part_sigma_s_per_mm`` (reduced scattering) and ``material.part_diffusion_mm`` (the
  diffusion length, which sets the absorption: :func:`absorption_per_mm`) the unknowns
  (:data:`PART_MEDIUM_PRIORS`, log-uniform; ``material.part_sigma_a_per_mm`` may replace the diffusion
  length in ``unknowns``), replacing the tag's
  tabulated medium (:func:`part_medium`; the boundary's η and α stay the tag's); a metal tag
  (``metal``, the old model) has ``material.metal_alpha`` (``knurled-metal``:
  ``material.knurled_alpha``) instead.

Known, not fitted: ``chain.jpeg_quality`` from the real JPEGs' quantisation tables
(:func:`sim.jpeg.jpeg_quality_of_file`; FabScan's scan-2_1: 95 exactly).  Left out, no key
for them: the translucent boundary's index η and roughness α, the medium's phase function
(isotropic, g = 0: σ_s is the reduced coefficient), the part's colour beyond its medium, and the
choice between a translucent and a metal part (the caller's ``part_material``, not fitted).

The fit is :func:`sim.identify.fit.fit_posterior`, as ``scheimpflug identify``'s: a Latin
hypercube of design runs over the priors, refinement runs where a first fit's tempered
posterior is, a Gaussian process per figure on its scale (:data:`FIGURE_SCALES`: log for
the stripe's width and peak, linear for fractions, contrasts and the background), MCMC (ABC when a surrogate is not
good enough).  A figure's measurement uncertainty is the standard error of the real
frames' median (1.2533 · sd / √n over the fitted frames, on its scale), at least
:data:`SIGMA_FLOOR` (what the twin cannot be asked to match closer); the twin's own
noise τ is the surrogates'.

Checks: the twin at the posterior median (each parameter's) is rendered at the fitted
frames and at the held-out ones, and each figure compared with the real one.  Its 90 %
predictive interval: at the fitted frames, the surrogate's prediction at posterior samples
with the twin's noise (mean, surrogate variance, τ²); at the held-out frames, the held-out
run's value plus the same spread around the median's prediction, with the noise of that
one run added (√2 τ): the surrogate knows the fitted frames only.

The runs render in spawned worker processes at once (``workers``, default :func:`default_workers`: one
per core while the memory holds them, each with cores / workers threads; each run rendered from its own
seed, as in one process — :mod:`sim.workers` renders frames alike; fresh workers after every
:data:`RUNS_PER_WORKER` runs each, as the renderer's per-medium caches grow): a twin's render alone keeps
about one core busy (FabScan's metal twin: 840 s of CPU in 769 s).  FabScan's
scan-2_1 (a translucent part): ≈ 13 s of CPU per run of 6 frames in a one-thread worker, against ≈ 11 s
for the metal part.

Files in ``out``: ``identify_scan.json`` (identity; a rerun with the same inputs resumes,
other inputs are refused), ``real.json`` (the real frames' figures per frame),
``runs/NNNNNN/run.json`` (one per run, as :mod:`sim.identify.runs` keeps them; the frame
folders removed), ``refine.json``, ``posterior.json``, ``identified.json`` (the result) and
``identified.toml`` (the rig with the identified values).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from scheimpflug.callbacks import ProgressCallback
from scheimpflug.dataset import file_sha256
from scheimpflug.errors import FrameError, RigError, StudyError
from scheimpflug.io.atomic import finite_json, write_json_atomic, write_text_atomic
from scheimpflug.model.rig import load_rig, rig_from_dict, rig_to_dict

from ..dataset.spec import sample_seed
from ..jobfolder import JobKind, open_job, remove_temporaries
from ..study.spec import _with_value
from .figures import from_scale, to_scale
from .fit import (
    DEFAULT_INFERENCE,
    _design_arrays,
    _surrogates,
    fit_posterior,
    observed_on_scale,
    parse_inference,
    refinement_draws,
)
from .job import identified_rig_text
from .posterior import resample
from .runs import RUN_FILE, run_folder
from .spec import FigureSpec, Parameter, _parse_parameter

_DEFAULT_INFERENCE = f"{DEFAULT_INFERENCE.surrogate}+{DEFAULT_INFERENCE.sampler}"

__all__ = ["DEFAULT_FRAMES", "DEFAULT_PART_MATERIAL", "FIGURE_SCALES", "PART_MEDIUM_KEYS", "PART_MEDIUM_PRIORS",
           "RUNS_PER_WORKER", "SCAN_FORMAT",
           "SIGMA_FLOOR", "ScanSpec", "absorption_per_mm", "default_frames", "default_unknowns", "identify_scan",
           "material_settings", "part_medium", "render_at_angles"]

SCAN_FORMAT = 1
META_FILE = "identify_scan.json"
REAL_FILE = "real.json"
POSTERIOR_FILE = "posterior.json"
REFINE_FILE = "refine.json"
RESULT_FILE = "identified.json"
IDENTIFIED_FILE = "identified.toml"
#: The image-level figures (:func:`scheimpflug.compare.figures.folder_figures`) and their scales: log for
#: the stripe's width and peak level; linear for fractions, contrasts and the background's level and
#: noise (a dark 8-bit background is 0 DN, which a log scale cannot hold).
FIGURE_SCALES = {"fwhm_px": "log", "peak_dn": "log", "saturated_fraction": "linear", "halo_fraction": "linear",
                 "background_dn": "linear", "noise_dn": "linear", "speckle_contrast": "linear",
                 "detection_rate": "linear"}
#: The least measurement uncertainty of each figure on its scale (what the twin cannot be asked to match
#: closer): 5 % of the width and of the peak level; 0.01 of a saturated fraction and of a contrast; 0.002
#: of a halo fraction (the halo holds 0.3–3 % of a stripe's light); half a DN of the background (an 8-bit
#: file's rounding) and 0.3 DN of its noise; 0.02 of a detection rate (a region's columns are counted).
SIGMA_FLOOR = {"fwhm_px": 0.05, "peak_dn": 0.05, "saturated_fraction": 0.01, "halo_fraction": 0.002,
               "background_dn": 0.5, "noise_dn": 0.3, "speckle_contrast": 0.01, "detection_rate": 0.02}
#: Frames fitted and held out by default (:func:`default_frames`) [-].
DEFAULT_FRAMES = 6
#: The part's material tag by default (:func:`identify_scan`): translucent, its medium identified.
DEFAULT_PART_MATERIAL = "white-plastic"
#: Priors of a translucent part's medium (log-uniform): the reduced scattering coefficient σ_s' over
#: plaster, resins and plastics (~0.5–50 /mm; the tabulated media of :data:`sim.materials.TRANSLUCENT`
#: hold 2.5–53 /mm) [1/mm] and the diffusion length L_d = 1/√(3 σ_a (σ_a + σ_s')) [mm], the decay length of
#: the glow's exponential wings, from 0.3 mm to 10 mm: over σ_s' ∈ [0.5, 50] that spans the absorption
#: σ_a ≈ 7·10⁻⁵–1.7 /mm (:func:`absorption_per_mm`).  Not σ_a itself: σ_a = 10⁻⁴ with σ_s' = 0.7 is a
#: 35 mm diffusion length, whose tabulated response (over ±6 L_d, :mod:`sim.subsurface`) took > 7 GB and
#: minutes for one full frame (measured; a worker was killed out of memory).  ``material.part_sigma_a_per_mm``
#: is accepted in ``unknowns`` instead of the diffusion length.
PART_MEDIUM_PRIORS = {"part_sigma_s_per_mm": (0.5, 50.0), "part_diffusion_mm": (0.3, 10.0)}
#: The material unknowns of a translucent part's medium (:func:`material_settings`).
PART_MEDIUM_KEYS = ("part_sigma_s_per_mm", "part_sigma_a_per_mm", "part_diffusion_mm")
#: Posterior samples behind a predictive interval [-].
_PREDICTIVE_SAMPLES = 400
_SE_MEDIAN = math.sqrt(math.pi / 2.0)      # the median's standard error over the mean's, Gaussian scatter
_MATERIAL = "material."
_SCAN_JOB = JobKind(error=StudyError, meta_file=META_FILE, noun="scan identification",
                    folder_noun="identification folder", owner="run",
                    what={"format": "another version of this program", "twin": "another twin",
                          "real": "other real frames", "setup": "other regions, frames or unknowns"},
                    differs=("output folder {out!r} holds a {noun} made with {what} ({where!r} differs); "
                             "choose another --out or delete the folder"))


@dataclass(frozen=True)
class ScanSpec:
    """What :func:`sim.identify.fit.fit_posterior` and :func:`identified_rig_text` read of a scan's fit.

    Parameters
    ----------
    name : str
        For the identified rig's header.
    seed : int
        Base seed: run k renders with ``sample_seed(seed, k)`` [-].
    runs, refine : int
        Latin-hypercube runs and refinement runs [-].
    posterior_draws : int
        Posterior draws kept (:func:`fit_posterior` needs them) [-].
    method : {"surrogate", "abc"}
        The estimate.
    parameters : tuple of Parameter
        The unknowns (rig keys, or ``material.FIELD``).
    fitted : tuple of FigureSpec
        The real frames' figures, ``REGION.FIGURE``, each with its scale and uncertainty.
    rig_tables : dict
        The twin's rig (the known values set).
    rig_source : str
        Where the rig came from.
    held_out : tuple
        Empty: a scan's held-out figures are its held-out frames' (:func:`identify_scan`).
    inference : str
        The inference backend, ``"SURROGATE+SAMPLER"`` (:func:`sim.identify.fit.parse_inference`).
    """

    name: str
    seed: int
    runs: int
    refine: int
    posterior_draws: int
    method: str
    parameters: tuple
    fitted: tuple
    rig_tables: dict
    rig_source: str
    held_out: tuple = ()
    inference: str = "hand+hand"

    @property
    def keys(self) -> list[str]:
        """The unknowns' keys, in order."""
        return [p.key for p in self.parameters]


@dataclass(frozen=True)
class _Scan:
    """The checked inputs: the twin, the real folder, the regions, the frames."""

    tables: dict
    part: Path
    housing: Path | None
    real: object
    regions: dict
    fit_frames: tuple
    held_frames: tuple
    channel: str | None
    known: dict
    part_material: str = "metal"


# ------------------------------------------------------------------ inputs


def default_frames(n_frames: int, parity: int, count: int = DEFAULT_FRAMES) -> list[int]:
    """``count`` frame indices of one parity spread over the turn.

    Parameters
    ----------
    n_frames : int
        Frames of the scan [-].
    parity : {0, 1}
        0: even-numbered frames (the fit's), 1: odd-numbered ones (held out).
    count : int
        How many [-].

    Returns
    -------
    list of int
        Sorted distinct indices (fewer when the scan has fewer of that parity); the odd ones
        half a spacing after the even ones.
    """
    pool = np.arange(parity, n_frames, 2)
    if len(pool) == 0:
        return []
    count = min(count, len(pool))
    pos = (np.arange(count) + 0.5 * parity) * len(pool) / count
    return sorted({int(pool[min(int(p), len(pool) - 1)]) for p in pos})


def default_unknowns(tables: dict, part_material: str = DEFAULT_PART_MATERIAL, sharpening: bool = False) -> dict:
    """The unknowns of a scan's twin and their priors (module docstring), around the rig's values.

    Parameters
    ----------
    tables : dict
        The twin's rig tables (``rig_to_dict``).
    part_material : str, default :data:`DEFAULT_PART_MATERIAL`
        The part's material tag: a translucent one has its medium's ``material.part_sigma_s_per_mm``
        and ``material.part_diffusion_mm`` (:data:`PART_MEDIUM_PRIORS`), ``metal`` its
        ``material.metal_alpha``, ``knurled-metal`` its ``material.knurled_alpha``.
    sharpening : bool, default False
        The camera's sharpening too, ``chain.sharpen_amount`` in [0, 2] and ``chain.sharpen_sigma_px``
        in [1, 30] px, log-uniform (off by default: on FabScan's scan it made the held-out part
        worse, ``benchmarks/RESULTS.md``).

    Returns
    -------
    dict
        Key → ``{"range": [lo, hi], "prior": …}``, as a spec's ``[parameters]``.
    """
    las, chain, env = tables["laser"], tables["chain"], tables["environment"]
    # the waist no thinner than the sheet's divergence allows (a Gaussian beam: θ ≥ λ / (π w0))
    thinnest_um = 1.01 * las["wavelength_nm"] / (math.pi * las["divergence_mrad"]) if las["divergence_mrad"] else 0
    # power × exposure: the rig's values are a preset's guesses; a real stripe may saturate at 100 × them
    out = {"laser.power_mw": {"range": [las["power_mw"] / 10.0, las["power_mw"] * 100.0], "prior": "log-uniform"},
           "laser.waist_um": {"range": [max(las["waist_um"] / 4.0, thinnest_um, 5.0), las["waist_um"] * 8.0],
                              "prior": "log-uniform"},
           "chain.glare_fraction": {"range": [0.0, 0.3]},
           "chain.glare_scale_um": {"range": [chain["glare_scale_um"] / 5.0, chain["glare_scale_um"] * 5.0],
                                    "prior": "log-uniform"},
           "chain.bloom_spill_fraction": {"range": [0.0, 1.0]},
           "chain.black_level_dn": {"range": [0.0, 4.0]},
           **({"chain.sharpen_amount": {"range": [0.0, 2.0]},
               "chain.sharpen_sigma_px": {"range": [1.0, 30.0], "prior": "log-uniform"}} if sharpening else {}),
           "laser.speckle_contrast": {"range": [0.0, 1.0]}}
    if env["ambient_irradiance_w_m2"] > 0:
        amb = env["ambient_irradiance_w_m2"]
        out["environment.ambient_irradiance_w_m2"] = {"range": [amb / 10.0, amb * 10.0], "prior": "log-uniform"}
    out["material.cardboard_albedo"] = {"range": [0.1, 0.9]}
    out.update(_part_unknowns(part_material))
    if chain["format"] == "png16":            # no camera chain: its keys do nothing
        out = {k: v for k, v in out.items() if not k.startswith("chain.")}
    return out


def _part_unknowns(part_material: str) -> dict:
    from ..materials import is_translucent

    if is_translucent(part_material):
        return {_MATERIAL + k: {"range": list(v), "prior": "log-uniform"} for k, v in PART_MEDIUM_PRIORS.items()}
    alpha = "knurled_alpha" if part_material == "knurled-metal" else "metal_alpha"
    return {_MATERIAL + alpha: {"range": [0.05, 1.0]}}


def absorption_per_mm(sigma_s_per_mm: float, diffusion_mm: float) -> float:
    """The absorption coefficient of a medium with this reduced scattering and diffusion length.

    The diffusion approximation's σ_eff = 1/L_d = √(3 σ_a (σ_a + σ_s')), solved for σ_a.

    Parameters
    ----------
    sigma_s_per_mm : float
        Reduced scattering coefficient σ_s' ≥ 0 [1/mm].
    diffusion_mm : float
        Diffusion length L_d > 0 [mm].

    Returns
    -------
    float
        σ_a = (√(σ_s'² + 4 / (3 L_d²)) − σ_s') / 2 [1/mm].
    """
    s = float(sigma_s_per_mm)
    return 0.5 * (math.sqrt(s * s + 4.0 / (3.0 * float(diffusion_mm) ** 2)) - s)


def part_medium(part_material: str, sigma_s_per_mm: float | None = None,
                sigma_a_per_mm: float | None = None):
    """A translucent tag's medium with its scattering and absorption coefficients replaced.

    Parameters
    ----------
    part_material : str
        A translucent tag of :data:`sim.materials.TRANSLUCENT` (its boundary's η and α are kept).
    sigma_s_per_mm, sigma_a_per_mm : float, optional
        The (reduced) scattering and the absorption coefficients [1/mm]; None keeps the tag's.

    Returns
    -------
    sim.materials.Translucent
        The medium.
    """
    from ..materials import TRANSLUCENT

    base = TRANSLUCENT[part_material]
    return replace(base, sigma_s_per_mm=base.sigma_s_per_mm if sigma_s_per_mm is None else float(sigma_s_per_mm),
                   sigma_a_per_mm=base.sigma_a_per_mm if sigma_a_per_mm is None else float(sigma_a_per_mm),
                   source="identified from the scan's frames (sim.identify.scan)")


def material_settings(values: dict, part_material: str | None) -> dict:
    """:class:`sim.materials.MaterialSettings` fields from material unknowns' values.

    Parameters
    ----------
    values : dict
        ``FIELD`` (without ``material.``) → value: fields of MaterialSettings, and
        ``part_sigma_s_per_mm``, ``part_sigma_a_per_mm`` or ``part_diffusion_mm`` (σ_a from it and
        σ_s', :func:`absorption_per_mm`), the part's medium.
    part_material : str or None
        The part's tag; the part's medium replaces that tag's in ``translucent``.

    Returns
    -------
    dict
        Keyword arguments of MaterialSettings (``translucent`` holding every tabulated medium, the
        part's replaced) .

    Raises
    ------
    ValueError
        A part medium's value without a translucent part tag.
    """
    from ..materials import TRANSLUCENT, is_translucent

    out = {k: v for k, v in values.items() if k not in PART_MEDIUM_KEYS}
    medium = {k: v for k, v in values.items() if k in PART_MEDIUM_KEYS}
    if medium:
        if part_material is None or not is_translucent(part_material):
            raise ValueError(f"{sorted(medium)[0]}: the part's medium needs a translucent part tag "
                             f"({', '.join(sorted(TRANSLUCENT))}), the part is {part_material or 'metal'!r}")
        if "part_sigma_a_per_mm" in medium and "part_diffusion_mm" in medium:
            raise ValueError("part_sigma_a_per_mm and part_diffusion_mm: give one (the diffusion length sets σ_a)")
        sigma_s = medium.get("part_sigma_s_per_mm", TRANSLUCENT[part_material].sigma_s_per_mm)
        sigma_a = medium.get("part_sigma_a_per_mm")
        if "part_diffusion_mm" in medium:
            sigma_a = absorption_per_mm(sigma_s, medium["part_diffusion_mm"])
        out["translucent"] = {**TRANSLUCENT, part_material: part_medium(part_material, sigma_s, sigma_a)}
    return out


def _fail(msg: str) -> StudyError:
    return StudyError(f"identify scan: {msg}")


def _twin_inputs(twin_dir: Path) -> tuple[dict, Path, Path | None]:
    if not twin_dir.is_dir():
        raise _fail(f"twin folder {str(twin_dir)!r} does not exist")
    rig_path, part = twin_dir / "rig.toml", twin_dir / "part.ply"
    for p in (rig_path, part):
        if not p.is_file():
            raise _fail(f"twin folder {str(twin_dir)!r} has no {p.name}")
    try:
        tables = rig_to_dict(load_rig(rig_path))
    except (RigError, OSError, ValueError) as exc:
        raise _fail(f"{str(rig_path)!r}: {exc}") from None
    housing = twin_dir / "housing.toml"
    return tables, part, housing if housing.is_file() and not tables.get("housing") else None


def _check_regions(regions, columns: int) -> dict:
    if not isinstance(regions, dict) or not regions:
        raise _fail(f"regions must be a non-empty mapping name → (lo_px, hi_px), got {regions!r}")
    out = {}
    for name, rng in regions.items():
        ok = isinstance(rng, (list, tuple)) and len(rng) == 2 and all(
            isinstance(v, (int, float)) and math.isfinite(v) for v in rng)
        if not (ok and 0 <= rng[0] < rng[1] <= columns):
            raise _fail(f"region {name!r} = {rng!r}: give (lo_px, hi_px) with 0 <= lo < hi <= {columns} "
                        "(the along-stripe image coordinate)")
        out[str(name)] = (float(rng[0]), float(rng[1]))
    return out


def _check_frames(what: str, frames, n: int) -> tuple:
    if not frames:
        raise _fail(f"no {what} frames: the scan of {n} frames has too few to "
                    f"{'fit' if what == 'fitted' else 'hold any out'}")
    bad = [f for f in frames if not (isinstance(f, (int, np.integer)) and 0 <= f < n)]
    if bad:
        raise _fail(f"{what} frame {bad[0]!r} is not a frame index of the scan (0 … {n - 1})")
    return tuple(sorted({int(f) for f in frames}))


def _known_jpeg(real, tables: dict) -> dict:
    """``chain.jpeg_quality`` from the real files' quantisation tables (module docstring)."""
    from ..jpeg import jpeg_quality_of_file

    src = real.frames[0].extra.get("source_file")
    if tables["chain"]["format"] != "jpeg" or not src or not Path(src).is_file():
        return {}
    try:
        q = jpeg_quality_of_file(src)
    except (ValueError, OSError):
        return {}
    return {"chain.jpeg_quality": {"value": int(q.quality), "exact": bool(q.exact),
                                   "source": f"the quantisation tables of {Path(src).name}"}}


def _others_materials(tables: dict, housing: Path | None) -> set:
    """The material tags of the twin's still objects: the table's disc and the housing's boards."""
    from scheimpflug.model.housing import load_housing

    tags = {tables["stage"].get("table_material", "cardboard")}
    boards = tables.get("housing") or []
    if housing is not None:
        try:
            boards = load_housing(housing)
        except (RigError, OSError, ValueError) as exc:
            raise _fail(f"{str(housing)!r}: {exc}") from None
    return tags | {b["material"] if isinstance(b, dict) else b.material for b in boards}


def _part_tables(tables: dict, housing: Path | None, part_material: str) -> dict:
    """The rig tables for a part of this tag: ``[twin] subsurface`` on for a translucent one (checked)."""
    from ..materials import MATERIALS, is_translucent

    if part_material not in MATERIALS:
        raise _fail(f"part material {part_material!r}: unknown material tag (known: {', '.join(MATERIALS)})")
    if not is_translucent(part_material):
        return tables
    shared = {part_material} & _others_materials(tables, housing)
    if shared:
        raise _fail(f"part material {part_material!r}: the table or the housing is of that tag too, and the "
                    "part's identified medium would be theirs: give the part another translucent tag "
                    f"(e.g. {DEFAULT_PART_MATERIAL!r})")
    return _with_value(tables, "twin.subsurface", True)


def _inputs(twin_dir, real_folder, regions, fit_frames, held_frames, part_material: str) -> _Scan:
    from scheimpflug.io.frames import open_frame_folder

    tables, part, housing = _twin_inputs(Path(twin_dir))
    tables = _part_tables(tables, housing, part_material)
    try:
        real = real_folder if hasattr(real_folder, "frames") else open_frame_folder(real_folder)
    except FrameError as exc:
        raise _fail(f"real frames: {exc}") from None
    angles = [r.angle_deg for r in real.frames]
    if any(a is None for a in angles):
        raise _fail(f"real folder {str(real.path)!r} has frames without angle_deg: import the scan with "
                    "--angles-deg (the twin renders at the real frames' angles)")
    size = (tables["sensor"]["rows"], tables["sensor"]["columns"])
    if (real.rows, real.columns) != size:
        raise _fail(f"the twin's sensor is {size[1]} × {size[0]} px but the real frames are "
                    f"{real.columns} × {real.rows}: a rig of another camera or binning")
    n = len(real.frames)
    fit = _check_frames("fitted", default_frames(n, 0) if fit_frames is None else fit_frames, n)
    held = _check_frames("held-out", default_frames(n, 1) if held_frames is None else held_frames, n)
    if set(fit) & set(held):
        raise _fail(f"frame {sorted(set(fit) & set(held))[0]} is fitted and held out: a held-out frame "
                    "is predicted, never fitted")
    known = _known_jpeg(real, tables)
    for key, k in known.items():
        tables = _with_value(tables, key, k["value"])
    along = real.columns if real.stripe_along == "rows" else real.rows
    manifest = json.loads((Path(real.path) / "manifest.json").read_text("utf-8"))
    return _Scan(tables, part, housing, real, _check_regions(regions, along), fit, held,
                 manifest.get("channel"), known, part_material)


def _parameters(unknowns: dict, tables: dict) -> tuple:
    out = []
    for key, value in unknowns.items():
        if key.startswith(_MATERIAL):
            out.append(_material_parameter(key, value))
        else:
            out.append(_parse_parameter("identify scan", key, value, tables))
    if not out:
        raise _fail("no unknowns to identify")
    return tuple(out)


def _material_parameter(key: str, value) -> Parameter:
    from ..materials import MaterialSettings

    field_name = key[len(_MATERIAL):]
    ok = isinstance(value, dict) and isinstance(value.get("range"), (list, tuple)) and len(value["range"]) == 2
    fields = ("cardboard_albedo", "tape_albedo", "metal_alpha", "knurled_alpha", *PART_MEDIUM_KEYS)
    if not ok or field_name not in fields:
        raise _fail(f"unknown {key!r} = {value!r}: material unknowns are material.cardboard_albedo, "
                    "tape_albedo, metal_alpha, knurled_alpha, part_sigma_s_per_mm, part_sigma_a_per_mm or "
                    "part_diffusion_mm with { range = [lo, hi] }")
    lo, hi = (float(v) for v in value["range"])
    try:
        if field_name in PART_MEDIUM_KEYS:
            if not (lo > 0 and math.isfinite(hi)):
                raise ValueError(f"a coefficient's range must lie in (0, inf) [1/mm], got [{lo:g}, {hi:g}]")
        else:
            MaterialSettings(**{field_name: lo}), MaterialSettings(**{field_name: hi})
    except (ValueError, TypeError) as exc:
        raise _fail(f"{key}: {exc}") from None
    if not lo < hi:
        raise _fail(f"{key}: the range [{lo:g}, {hi:g}] is empty or reversed")
    prior = value.get("prior", "uniform")
    return Parameter(key, lo, hi, "log-uniform" if prior == "log-uniform" and lo > 0 else "uniform")


# ------------------------------------------------------------------ one run: render, import, measure


def render_at_angles(tables: dict, part, housing, angles_deg, out, *, seed: int,
                     materials: dict | None = None, part_material: str | None = None) -> Path:
    """Render the twin's rotary scan at given turntable angles into a frame folder (resumable).

    Parameters
    ----------
    tables : dict
        The rig tables.
    part : path
        The part's mesh.
    housing : path or None
        A housing file (None: the rig's own housing, or none).
    angles_deg : sequence of float
        The frames' turntable angles [deg], frame i at ``angles_deg[i]``.
    out : path
        The frame folder.
    seed : int
        Render seed [-].
    materials : dict, optional
        :class:`sim.materials.MaterialSettings` fields.
    part_material : str, optional
        The part's material tag (default the mesh's, ``metal``); a translucent one renders its
        medium when the rig's ``[twin] subsurface`` is on.

    Returns
    -------
    Path
        ``out``.
    """
    from ..materials import MaterialSettings
    from ..writer import MitsubaTwin, build_run, render_scenario

    rig = rig_from_dict(tables)
    settings = MaterialSettings(**(materials or {}))

    def twin_factory(rig_, assembly, **kw):
        return MitsubaTwin(rig_, assembly, materials=settings, **kw)

    options = {"part": str(part), "angles_deg": [float(a) for a in angles_deg], "truth_pixels_every": 0}
    if part_material is not None:
        options["part_material"] = part_material
    if housing is not None:
        options["housing"] = str(housing)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")              # the mesh's MeshWarnings: the twin build's to say
        scenario, twin, manifest, _ = build_run(rig, "rotary", seed, None, options, twin_factory=twin_factory)
    render_scenario(rig, scenario, Path(out), twin, manifest, warn=lambda msg: None)
    return Path(out)


def _grey_folder(rendered: Path, out: Path, channel: str | None, stripe_along: str) -> Path:
    """A chain's colour frames read as the real ones were imported (``channel``); grey frames as they are.

    The path ``compare`` takes (:func:`scheimpflug.io.twin_frames.grey_twin_frames`): the importer with
    the rendered angles, the real folder's ``channel`` and its ``stripe_along`` *known* (the twin's
    camera is the real one: not detected, so a faint or glaring stripe cannot make a run refuse).
    Frame i of the folder returned is rendered frame i (the importer orders frames by angle: the
    rendered angles must not decrease).  ``out`` is rebuilt (a killed run's copy removed).
    """
    from scheimpflug.io.twin_frames import grey_twin_frames

    angles = [f.get("angle_deg") for f in json.loads((rendered / "manifest.json").read_text("utf-8"))["frames"]]
    if any(b is not None and a is not None and b < a for a, b in zip(angles, angles[1:])):
        raise StudyError(f"{str(rendered)!r}: the rendered angles decrease; the grey frames would come in "
                         "another order than the run's frames")
    shutil.rmtree(out, ignore_errors=True)
    return grey_twin_frames(rendered, out, channel=channel, stripe_along=stripe_along)


def _per_frame(folder, regions: dict, frames) -> dict:
    """``{"REGION.FIGURE": [value per frame (None: not measured)]}`` of a frame folder."""
    from scheimpflug.compare.figures import folder_figures as figures
    from scheimpflug.io.frames import open_frame_folder

    folder = folder if hasattr(folder, "frames") else open_frame_folder(folder)
    out: dict = {}
    for i in frames:
        got = figures(folder, regions, frames=[int(i)])
        for region, values in got.items():
            for name, v in values.items():
                if name in FIGURE_SCALES:
                    ok = v is not None and math.isfinite(v)
                    out.setdefault(f"{region}.{name}", []).append(float(v) if ok else None)
    return out


def _valid(scale: str, v) -> bool:
    return v is not None and math.isfinite(v) and (scale != "log" or v > 0)


def _medians(per_frame: dict) -> dict:
    out = {}
    for name, values in per_frame.items():
        scale = FIGURE_SCALES[name.rsplit(".", 1)[1]]
        good = [v for v in values if _valid(scale, v)]
        out[name] = float(np.median(good)) if good else None
    return out


@dataclass(frozen=True)
class _RunPlan:
    index: int
    role: str
    seed: int
    unit: tuple
    values: dict
    frames: tuple


def _run_one(plan: _RunPlan, scan: _Scan, out: Path) -> dict:
    """Render, import and measure one run (resumable as :func:`sim.identify.runs.run_one`)."""
    final = run_folder(out, plan.index)
    if (final / RUN_FILE).is_file():
        return json.loads((final / RUN_FILE).read_text("utf-8"))
    if final.exists():
        raise _fail(f"run folder {str(final)!r} exists but has no {RUN_FILE}: delete it and rerun")
    t0, c0 = time.perf_counter(), time.process_time()
    partial = run_folder(out, plan.index, partial=True)
    partial.mkdir(parents=True, exist_ok=True)
    tables, materials = scan.tables, {}
    for key, v in plan.values.items():
        if key.startswith(_MATERIAL):
            materials[key[len(_MATERIAL):]] = v
        else:
            tables = _with_value(tables, key, v)
    angles = [scan.real.frames[i].angle_deg for i in plan.frames]
    rendered = render_at_angles(tables, scan.part, scan.housing, angles, partial / "render", seed=plan.seed,
                                materials=material_settings(materials, scan.part_material),
                                part_material=scan.part_material)
    grey = _grey_folder(rendered, partial / "frames", scan.channel, scan.real.stripe_along)
    per_frame = _per_frame(grey, scan.regions, range(len(angles)))
    record = {"run": plan.index, "role": plan.role, "seed": plan.seed, "values": plan.values,
              "unit": list(plan.unit), "frames": list(plan.frames), "figures": _medians(per_frame),
              "per_frame": per_frame, "reasons": {},
              "seconds": {"wall": time.perf_counter() - t0, "cpu": time.process_time() - c0}}
    for p in partial.iterdir():
        if p.is_dir():
            shutil.rmtree(p)
    write_json_atomic(partial / RUN_FILE, finite_json(record))
    os.replace(partial, final)
    return record


# ------------------------------------------------------------------ the observations


def _observed(per_frame: dict, names=None) -> dict:
    """Per figure: the real median, its uncertainty (module docstring) and scale; unmeasured ones left out."""
    out = {}
    for name, values in per_frame.items():
        if names is not None and name not in names:
            continue
        scale = FIGURE_SCALES[name.rsplit(".", 1)[1]]
        good = np.array([to_scale(scale, v) for v in values if _valid(scale, v)])
        if len(good) == 0:
            continue
        se = _SE_MEDIAN * float(np.std(good, ddof=1)) / math.sqrt(len(good)) if len(good) > 1 else 0.0
        sigma = max(se, SIGMA_FLOOR[name.rsplit(".", 1)[1]])
        med = float(np.median([v for v in values if _valid(scale, v)]))
        out[name] = {"measured": med, "scale": scale, "sigma": sigma, "frames_measured": int(len(good))}
    return out


def _figure_specs(observed: dict, records: list, least: int) -> tuple[tuple, dict]:
    """The fitted figures: measured on the real frames and by at least ``least`` design runs."""
    specs, dropped = [], {}
    for name, o in observed.items():
        n = sum(_valid(o["scale"], r["figures"].get(name)) for r in records)
        if n < least:
            dropped[name] = f"measured by {n} of {len(records)} design runs (need {least})"
            continue
        # the uncertainty on the figure's scale: absolute for linear, relative (σ on ln) for log
        kw = {"relative": o["sigma"]} if o["scale"] == "log" else {"absolute": o["sigma"]}
        specs.append(FigureSpec(name, o["measured"], scale=o["scale"], **kw))
    return tuple(specs), dropped


# ------------------------------------------------------------------ the job


def _identity(scan: _Scan, twin_dir: Path, unknowns: dict, runs: int, refine: int, seed: int,
              inference: str) -> dict:
    twin = {p.name: file_sha256(p) for p in (twin_dir / "rig.toml", scan.part, scan.housing) if p is not None}
    real = {"path": str(Path(scan.real.path).resolve()),
            "manifest": file_sha256(Path(scan.real.path) / "manifest.json")}
    setup = {"regions": {k: list(v) for k, v in scan.regions.items()}, "fit_frames": list(scan.fit_frames),
             "held_frames": list(scan.held_frames), "unknowns": unknowns, "runs": runs, "refine": refine,
             "seed": seed, "figures": sorted(FIGURE_SCALES), "part_material": scan.part_material}
    if inference != _DEFAULT_INFERENCE:          # recorded when not the default: earlier folders still resume
        setup["inference"] = inference
    return {"format": SCAN_FORMAT, "kind": "identify-scan", "twin": twin, "real": real,
            "setup": json.loads(json.dumps(setup))}


def _real_figures(scan: _Scan, out: Path) -> dict:
    path = out / REAL_FILE
    if path.is_file():
        return json.loads(path.read_text("utf-8"))
    got = {"fit": _per_frame(scan.real, scan.regions, scan.fit_frames),
           "held": _per_frame(scan.real, scan.regions, scan.held_frames)}
    write_json_atomic(path, finite_json(got))
    return got


class _Counter:
    def __init__(self, progress, total: int, workers: int = 1) -> None:
        self.progress, self.total, self.done, self.workers = progress, total, 0, workers

    def step(self) -> None:
        self.done += 1
        if self.progress:
            self.progress(self.done, self.total)


def _plans(spec: ScanSpec, units, first: int, role: str, frames: tuple) -> list[_RunPlan]:
    out = []
    for i, u in enumerate(units):
        k = first + i
        values = {p.key: float(p.value(float(q))) for p, q in zip(spec.parameters, u)}
        out.append(_RunPlan(k, role, sample_seed(spec.seed, k), tuple(float(q) for q in u), values, frames))
    return out


def _design_units(seed: int, n: int, d: int) -> np.ndarray:
    from scipy.stats import qmc

    rng = np.random.default_rng(np.random.SeedSequence((seed, 0x1DE7)))
    return qmc.LatinHypercube(d=d, seed=rng).random(n)


def _load_json(path: Path, make):
    if path.is_file():
        try:
            return json.loads(path.read_text("utf-8"))
        except (OSError, ValueError) as exc:
            raise _fail(f"{str(path)!r} cannot be read ({exc}): delete it and rerun") from None
    value = finite_json(json.loads(json.dumps(make(), default=float)))
    write_json_atomic(path, value)
    return value


def identify_scan(twin_dir, real_folder, regions, *, fit_frames=None, held_frames=None, out, runs=None,
                  progress: ProgressCallback | None = None, unknowns: dict | None = None, refine: int | None = None,
                  seed: int = 0, warn: Callable[[str], None] | None = None,
                  part_material: str = DEFAULT_PART_MATERIAL, workers: int | None = None,
                  inference: str | None = None, sharpening: bool = False) -> dict:
    """Identify the twin's unknowns from the real scan's frames (module docstring).

    Parameters
    ----------
    twin_dir : path
        The twin folder: ``rig.toml``, ``part.ply``, optionally ``housing.toml``.
    real_folder : path or FrameFolder
        The real scan, imported (grey frames with ``angle_deg``; the frame size the rig's).
    regions : dict
        Region name → (lo, hi) of the along-stripe image coordinate [px]
        (:func:`scheimpflug.still_points.still_regions`).
    fit_frames, held_frames : sequence of int, optional
        Real frames fitted and held out (default: :data:`DEFAULT_FRAMES` even-numbered ones and as
        many odd-numbered ones, spread over the turn); disjoint.
    out : path
        The identification folder (created; a rerun resumes).
    runs : int, optional
        Latin-hypercube design runs (default ``max(8, 5 d)``, d the unknowns).
    progress : ProgressCallback, optional
        ``progress(done, total)`` after each run.
    unknowns : dict, optional
        Key → ``{"range": [lo, hi], "prior": …}`` (default :func:`default_unknowns`).
    sharpening : bool, default False
        With the default unknowns: the camera's sharpening among them (:func:`default_unknowns`).
    refine : int, optional
        Refinement runs (default ``max(4, runs // 2)``; 0 = none).
    seed : int
        Base seed [-].
    warn : callable, optional
        Receives warnings (the ABC fallback, figures left out), one line each.
    part_material : str, default :data:`DEFAULT_PART_MATERIAL`
        The part's material tag (:data:`sim.materials.MATERIALS`); a translucent one renders its
        medium (``[twin] subsurface`` set on), identified by ``material.part_sigma_s_per_mm`` and
        ``material.part_diffusion_mm``; it must not be the table's or the housing's tag.
    workers : int, optional
        Processes rendering runs at once (spawned, each with cores / workers threads, each run
        rendered from its own seed, fresh ones after every :data:`RUNS_PER_WORKER` runs each); default
        :func:`default_workers`.
    inference : str, optional
        The inference backend, ``"SURROGATE+SAMPLER"`` (:func:`sim.identify.fit.parse_inference`;
        default ``hand+hand``); another one is recorded in the folder's identity.

    Returns
    -------
    dict
        ``part_material`` (``tag``; ``medium``: for a translucent tag the medium at the posterior
        medians, :class:`sim.materials.Translucent`'s fields, else None), ``identified`` (per
        unknown: ``value`` (posterior median), ``lo90``, ``hi90``, ``prior``, ``identifiable``,
        ``at_prior_edge``, ``rig_key``), ``known`` (values fixed from the frames),
        ``figures`` (``fitted`` and ``held_out``: per ``REGION.FIGURE`` the ``real`` and ``twin``
        values, ``lo90``, ``hi90``, ``inside``), ``not_fitted`` (figure → why), ``fit`` (method,
        fallback, surrogates' cross-validation, MCMC diagnostics), ``runs`` (``count``, ``wall_s``,
        ``cpu_s``, ``per_run_wall_s``), ``files``.

    Raises
    ------
    StudyError
        One error naming the problem: a missing twin file, real frames without angles or of
        another size, bad regions or frames (none to fit or hold out, overlapping), an unknown
        key or a prior outside its key's range, an unknown part tag or one the table or housing
        has too, an output folder holding another job.
    """
    warn = warn or (lambda msg: None)
    scan = _inputs(twin_dir, real_folder, regions, fit_frames, held_frames, part_material)
    unknowns = dict(default_unknowns(scan.tables, part_material, sharpening) if unknowns is None else unknowns)
    try:               # a part medium's unknown with a metal part: refused
        material_settings({k[len(_MATERIAL):]: 1.0 for k in unknowns if k.startswith(_MATERIAL)}, part_material)
    except ValueError as exc:
        raise _fail(str(exc)) from None
    params = _parameters(unknowns, scan.tables)
    d = len(params)
    runs = max(8, 5 * d) if runs is None else int(runs)
    if runs < max(5, d + 2):
        raise _fail(f"runs = {runs}: {d} unknowns need at least {max(5, d + 2)} design runs")
    refine = max(4, runs // 2) if refine is None else int(refine)
    out = Path(out)
    backend = parse_inference(inference)
    inference = f"{backend.surrogate}+{backend.sampler}"
    identity = _identity(scan, Path(twin_dir), unknowns, runs, refine, seed, inference)
    with open_job(out, _SCAN_JOB, identity, warn):
        (out / "runs").mkdir(parents=True, exist_ok=True)
        remove_temporaries(out, ("runs",))
        write_json_atomic(out / META_FILE, {**identity, "complete": False})
        n_workers = default_workers() if workers is None else max(1, int(workers))
        result = _identify(scan, params, runs, refine, seed, out, _Counter(progress, runs + refine + 2, n_workers),
                           warn, inference)
        result["files"] = {"identified_rig": str(out / IDENTIFIED_FILE), "result": str(out / RESULT_FILE)}
        write_json_atomic(out / RESULT_FILE, finite_json(json.loads(json.dumps(result, default=float))))
        write_json_atomic(out / META_FILE, {**identity, "complete": True})
    return result


def _identify(scan: _Scan, params: tuple, runs: int, refine: int, seed: int, out: Path, count: _Counter,
              warn, inference: str = "hand+hand") -> dict:
    t0 = time.perf_counter()
    real = _real_figures(scan, out)
    spec = ScanSpec(name="scan", seed=seed, runs=runs, refine=refine, posterior_draws=20, method="surrogate",
                    parameters=params, fitted=(), rig_tables=scan.tables, rig_source="twin rig.toml",
                    inference=inference)
    records = _runs(_plans(spec, _design_units(seed, runs, len(params)), 0, "design", scan.fit_frames), scan,
                    out, count)
    observed = _observed(real["fit"])
    fitted, dropped = _figure_specs(observed, records, max(5, len(params) + 2))
    for name, why in dropped.items():
        warn(f"{name} not fitted: {why}")
    if not fitted:
        raise _fail("no figure of the real frames could be fitted (every one unmeasured by the real frames or "
                     "by the twin's runs): check the regions")
    spec = replace(spec, fitted=fitted)
    if refine:       # placed by every figure's first surrogate, as `identify` places them
        units = _load_json(out / REFINE_FILE, lambda: {"units": refinement_draws(spec, records)})["units"]
        records += _runs(_plans(spec, units, runs, "refine", scan.fit_frames), scan, out, count)
    spec = _followed(spec, records, dropped, warn)
    with np.errstate(invalid="ignore", divide="ignore"):      # a figure constant over the runs: no correlation
        fit = _load_json(out / POSTERIOR_FILE, lambda: fit_posterior(spec, records, warn=warn))
    median = _median_unit(spec, fit)
    first = runs + refine
    checks = _runs(_plans(spec, [median], first, "check", scan.fit_frames)
                   + _plans(spec, [median], first + 1, "held-out", scan.held_frames), scan, out, count)
    figures = _check_figures(spec, fit, records, median, checks, real, seed)
    identified = _identified(fit, spec)
    write_text_atomic(out / IDENTIFIED_FILE, _rig_text(spec, fit, identified, scan.known))
    every = records + checks
    return {"part_material": _part_result(scan.part_material, identified), "identified": identified,
            "known": scan.known, "figures": figures, "not_fitted": dropped,
            "fit": {k: fit.get(k) for k in ("method", "fallback", "surrogate_cv_error", "mcmc", "abc")},
            "frames": {"fit": list(scan.fit_frames), "held_out": list(scan.held_frames)},
            "runs": {"count": len(every), "design": runs, "refine": refine, "checks": len(checks),
                     "wall_s": time.perf_counter() - t0, "cpu_s": sum(r["seconds"]["cpu"] for r in every),
                     "per_run_wall_s": float(np.median([r["seconds"]["wall"] for r in every]))}}


def _part_result(part_material: str, identified: dict) -> dict:
    """The part's tag and, for a translucent one, its medium at the posterior medians."""
    from dataclasses import asdict

    from ..materials import is_translucent

    if not is_translucent(part_material):
        return {"tag": part_material, "medium": None}
    values = {k[len(_MATERIAL):]: v["value"] for k, v in identified.items()
              if k[len(_MATERIAL):] in PART_MEDIUM_KEYS}
    medium = material_settings(values, part_material)["translucent"][part_material] if values else \
        part_medium(part_material)
    return {"tag": part_material, "medium": asdict(medium)}


def _followed(spec: ScanSpec, records: list, dropped: dict, warn) -> ScanSpec:
    """The spec without the figures whose surrogate cannot follow the runs within the figure's uncertainty.

    :func:`fit_posterior` would fall back to ABC on the design runs for them; with tens of runs over
    several unknowns that weighs one or two runs (an effective sample size near 1), not a posterior.
    A figure left out is said (``dropped``, ``warn``); none left is an error.
    """
    from threadpoolctl import threadpool_limits

    units, values = _design_arrays(spec, records)
    with threadpool_limits(limits=1, user_api="blas"):
        _, sigma = observed_on_scale(spec)
        _, cv = _surrogates(spec, units, values, sigma)
    keep = []
    for f in spec.fitted:
        c = cv[f.name]
        if c["ok"]:
            keep.append(f)
            continue
        dropped[f.name] = (f"the surrogate cannot follow it within its uncertainty over {c['n']} runs "
                           f"(error {c['error']:.3g} >= {c['uncertainty']:.3g} on its {c['scale']} scale)")
        warn(f"{f.name} not fitted: {dropped[f.name]}")
    if not keep:
        raise _fail("no figure's surrogate follows the twin's runs within its uncertainty: more runs, narrower "
                    "priors or other regions")
    return replace(spec, fitted=tuple(keep))


def _runs(plans: list, scan: _Scan, out: Path, count: _Counter) -> list[dict]:
    """The plans' records, in order, rendered on ``count.workers`` worker processes (resumable alike).

    The runs not done yet go in batches of ``workers`` × :data:`RUNS_PER_WORKER`, each batch on a fresh
    pool (a worker's memory grows run by run; the pool's own ``max_tasks_per_child`` hung on Python 3.11).
    """
    from concurrent.futures import as_completed
    from concurrent.futures.process import BrokenProcessPool

    records: list = [None] * len(plans)
    todo = []
    for i, plan in enumerate(plans):
        if (run_folder(out, plan.index) / RUN_FILE).is_file():
            records[i] = _run_one(plan, scan, out)          # done before: read back
            count.step()
        else:
            todo.append(i)
    batch = max(1, count.workers) * RUNS_PER_WORKER
    for first in range(0, len(todo), batch):
        part = todo[first:first + batch]
        pool = _run_pool(scan, min(count.workers, len(part)))
        try:
            futures = {pool.submit(_worker_run, plans[i], str(out)): i for i in part}
            for fut in as_completed(futures):
                records[futures[fut]] = fut.result()
                count.step()
        except BrokenProcessPool:
            raise _fail(f"a run's worker process ended unexpectedly (killed, or out of memory? each needs "
                        f"about {WORKER_BYTES / 1e9:.0f} GB) with runs of this batch unfinished; the runs "
                        "already done are kept: rerun to resume") from None
        finally:
            pool.shutdown(wait=True, cancel_futures=True)
    return records


# ------------------------------------------------------------------ runs in worker processes

_WORKER: dict = {}
#: Runs a worker renders before it is replaced by a fresh one: the renderer keeps per-process caches of
#: each medium's tabulated response and its kernels (:mod:`sim.transport`), and every run of a
#: translucent part has a medium of its own — measured +0.2–0.3 GB of resident memory per run in one
#: process (FabScan's twin: 1.0 GB after the first run, 2.4 GB after the fifth; a worker of the 84-run
#: identification reached 14.5 GB without replacement; the renderer now keeps at most
#: :data:`sim.transport.MAX_CACHED_MEDIA` media, and fresh workers stay as the guard) [-].
RUNS_PER_WORKER = 6
#: Resident memory of one run's worker: 1 GB after its first run of the FabScan twin, up to about
#: 1 + 0.3 × :data:`RUNS_PER_WORKER` GB before it is replaced, with margin [B].
WORKER_BYTES = 4.0e9


def default_workers(n_cores: int | None = None, ram_bytes: float | None = None) -> int:
    """Worker processes for the runs: one per core, as many as the memory holds (:data:`WORKER_BYTES`).

    Parameters
    ----------
    n_cores : int, optional
        Cores (default :func:`sim.threads.cores`) [-].
    ram_bytes : float, optional
        Memory (default the machine's) [B].

    Returns
    -------
    int
        At least 1 [-].
    """
    from ..threads import cores

    n = cores() if n_cores is None else int(n_cores)
    if ram_bytes is None:
        ram_bytes = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    return max(1, min(n, int(ram_bytes // WORKER_BYTES)))


def _init_run_worker(scan: _Scan, threads: int) -> None:
    """Worker initializer: ignores SIGINT (the main process stops it), dies with it, sizes its threads."""
    import signal

    from ..threads import configure_threads
    from ..workers import _die_with_parent

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _die_with_parent()
    configure_threads(threads)
    _WORKER["scan"] = scan


def _worker_run(plan: _RunPlan, out: str) -> dict:
    return _run_one(plan, _WORKER["scan"], Path(out))


def _run_pool(scan: _Scan, workers: int):
    """A pool of ``workers`` spawned processes for the runs.

    One worker too (not this process): its memory grows run by run (:data:`RUNS_PER_WORKER`).
    """
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from ..threads import cores

    workers = max(1, int(workers))
    return ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_init_run_worker, initargs=(scan, max(1, cores() // workers)))


# ------------------------------------------------------------------ the result


def _median_unit(spec: ScanSpec, fit: dict) -> list[float]:
    return [float(p.unit(row["median"])) for p, row in zip(spec.parameters, fit["summary"]["parameters"])]


def _posterior_samples(fit: dict, seed: int) -> np.ndarray:
    samples = np.asarray(fit["samples"], dtype=np.float64)
    if fit.get("weights") is not None:
        return resample(samples, np.asarray(fit["weights"]), _PREDICTIVE_SAMPLES, seed)
    step = max(1, len(samples) // _PREDICTIVE_SAMPLES)
    return samples[::step][:_PREDICTIVE_SAMPLES]


def _check_figures(spec, fit, records, median, checks, real, seed: int) -> dict:
    """Fitted and held-out figures: real, twin at the median, the 90 % predictive interval, inside."""
    from threadpoolctl import threadpool_limits

    units, values = _design_arrays(spec, records)
    with threadpool_limits(limits=1, user_api="blas"):
        obs, sigma = observed_on_scale(spec)
        models, _ = _surrogates(spec, units, values, sigma)
    xs = _posterior_samples(fit, seed)
    rng = np.random.default_rng(np.random.SeedSequence((seed, 0x5CA9)))
    held_obs = _observed(real["held"])
    out = {"fitted": {}, "held_out": {}}
    for f, gp in zip(spec.fitted, models):
        mu, var = gp.predict(xs)
        mu0, _ = gp.predict(np.atleast_2d(median))
        eps = rng.standard_normal(len(xs))
        tau = gp.noise_sd
        fitted_z = mu + np.sqrt(var + tau ** 2) * eps
        out["fitted"][f.name] = _row(f.stat_scale, f.measured, checks[0]["figures"].get(f.name), fitted_z)
        twin = checks[1]["figures"].get(f.name)
        if f.name in held_obs and _valid(f.stat_scale, twin):
            spread = mu - mu0[0] + np.sqrt(var + 2.0 * tau ** 2) * eps
            z = to_scale(f.stat_scale, twin) + spread
            out["held_out"][f.name] = _row(f.stat_scale, held_obs[f.name]["measured"], twin, z)
    _unfitted_rows(out["fitted"], _observed(real["fit"]), checks[0])
    _unfitted_rows(out["held_out"], held_obs, checks[1])
    return out


def _unfitted_rows(rows: dict, observed: dict, check: dict) -> None:
    """The figures not fitted, real against the twin at the median, without an interval (``inside`` None)."""
    for name, o in observed.items():
        if name not in rows:
            twin = check["figures"].get(name)
            rows[name] = {"real": o["measured"], "twin": twin if _valid(o["scale"], twin) else None,
                          "lo90": None, "hi90": None, "inside": None}


def _row(scale: str, real: float, twin, z: np.ndarray) -> dict:
    lo, hi = (float(from_scale(scale, q)) for q in np.quantile(z, [0.05, 0.95]))
    return {"real": real, "twin": twin if _valid(scale, twin) else None, "lo90": lo, "hi90": hi,
            "inside": bool(lo <= real <= hi)}


def _identified(fit: dict, spec: ScanSpec) -> dict:
    out = {}
    for p, row in zip(spec.parameters, fit["summary"]["parameters"]):
        out[p.key] = {"value": row["median"], "lo90": row["lo90"], "hi90": row["hi90"], "mean": row["mean"],
                      "prior": row["prior"], "identifiable": row["identifiable"],
                      "at_prior_edge": row["at_prior_edge"], "rig_key": not p.key.startswith(_MATERIAL)}
    return out


def _rig_text(spec: ScanSpec, fit: dict, identified: dict, known: dict) -> str:
    """The twin's rig with the identified values (posterior medians), as :func:`identified_rig_text` writes it."""
    rows = [dict(r, mean=r["median"]) for p, r in zip(spec.parameters, fit["summary"]["parameters"])
            if not p.key.startswith(_MATERIAL)]
    rig_params = tuple(p for p in spec.parameters if not p.key.startswith(_MATERIAL))
    text = identified_rig_text(replace(spec, parameters=rig_params, name="scan"),
                               {"parameters": rows, "held_out": [], "method": fit["method"]})
    text = text.replace("the posterior means of", "the posterior medians of").replace(
        "this mean is the prior's", "this median is the prior's")
    extra = [f"# Known from the frames: {k} = {v['value']} ({v['source']})." for k, v in known.items()]
    extra += [f"# Identified, not a rig key (the renderer's sim.materials.MaterialSettings): {k} = "
              f"{v['value']:.4g}, 90 % interval [{v['lo90']:.4g}, {v['hi90']:.4g}]."
              for k, v in identified.items() if not v["rig_key"]]
    return "\n".join(extra + [text]) if extra else text
