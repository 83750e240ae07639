"""Dataset specs (TOML): what every sample of a regression dataset draws, and from which seed.

Format (lengths in mm, angles in degrees; examples in ``datasets/examples/``)::

    [dataset]
    seed = 1                  # base seed; sample k's seed derives from (seed, k) only
    samples = 100             # number of samples (k = 0 … samples − 1)
    name = "cylinder-roll"    # optional (default: the file name)
    description = "…"         # optional, copied into the dataset card

    [rig]
    preset = "paper"          # or file = "RIG.toml" (relative to the spec file)
    [rig.variation]           # rig keys "table.key" drawn per sample
    "sensor.roll_deg" = [-0.2, 0.2]                  # uniform in [lo, hi]
    "laser.speckle_contrast" = { choices = [0.0, 0.5] }
    "stage.axis_mm" = { normal = [179.45, 0.05] }    # normal(mean, sigma)

    [scenario]
    kind = "rotary"           # calibration | blocker | rotary
    part = "cylinder"         # rotary: preset name, mesh file or scene file (relative paths)
    step_deg = 3.0            # any option of the scenario (sim.scenarios): calibration:
    frames = 8                #   steps, step_mm, start_mm, plate_height_mm; blocker: frames,
    binning = 1               #   thickness_mm; rotary: part, step_deg, frames
    spp = 32                  # optional: laser samples per lit row (renderer default)
    material = "metal"        # optional: every part's material tag (sim.materials)
    truth_pixels = "none"     # per-pixel truth maps: "none" (default) | "every" | N (png only)
    [scenario.variation]      # scenario keys drawn per sample
    part = { choices = ["cylinder", "sphere", "parts/bracket.stl"] }
    material = { choices = ["metal", "cardboard"] }
    step_deg = [2.0, 4.0]

    [materials]               # sim.materials.MaterialSettings values (albedo, GGX roughness)
    cardboard_albedo = 0.35
    [materials.variation]
    metal_alpha = [0.1, 0.4]

A variation is ``[lo, hi]`` (uniform; integers in [lo, hi] for integer keys),
``{ choices = [...] }`` or ``{ normal = [mean, sigma] }``; a plain value fixes
the key.  Every unknown key, an empty or reversed range (lo ≥ hi), an empty
``choices`` list or a non-positive sigma is a :class:`DatasetError` naming the key.

Seeds.  Sample k's seed is ``sample_seed(seed, k)`` (32 bit, from
``SeedSequence((seed, k, 0xDA7A))``): the scenario's frame seeds, the renderer,
the sensor noise and scene-file variations of sample k derive from it.  Each
varied key draws from its own generator, ``SeedSequence((seed, k,
crc32(section.key)))``, so adding a variation leaves the other keys' draws as
they were.  Nothing depends on the number of workers or on the order in which
samples finish: any sample regenerates alone.
"""

from __future__ import annotations

import hashlib
import inspect
import json
import math
import os
import zlib
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from scenes import PART_NAMES
from scheimpflug.errors import DatasetError, ScheimpflugError
from scheimpflug.model.binning import binned_rig
from scheimpflug.model.chain import chain_is_on
from scheimpflug.model.rig import PRESETS, Rig, load_preset, load_rig, read_toml, rig_from_dict, rig_to_dict

from ..materials import MaterialSettings
from ..render_limits import check_laser_samples

__all__ = [
    "DatasetSpec",
    "SamplePlan",
    "frames_bound",
    "load_spec",
    "parse_spec",
    "plan_sample",
    "planned_frames",
    "sample_seed",
]

_STREAM_SAMPLE = 0xDA7A
_TOP = {"dataset", "rig", "scenario", "materials"}
_DATASET_KEYS = {"seed", "samples", "name", "description"}
_RIG_KEYS = {"preset", "file", "variation"}
_KINDS = ("blocker", "calibration", "rotary")
#: scenario keys every kind accepts (besides its own options)
_COMMON = {"kind", "binning", "spp", "material", "truth_pixels", "variation"}
#: the options of each kind: spec key → keyword of the sim.scenarios builder
_OPTIONS = {
    "calibration": {"steps": "steps", "step_mm": "step_mm", "start_mm": "start_mm",
                    "plate_height_mm": "plate_height_mm"},
    "blocker": {"frames": "frames", "thickness_mm": "thickness_mm"},
    "rotary": {"part": "part", "step_deg": "step_deg", "frames": "frames"},
}
_INT_KEYS = {"steps", "frames", "binning", "spp"}
_MATERIAL_TAGS = ("cardboard", "knurled-metal", "metal", "tape")


@dataclass(frozen=True)
class DatasetSpec:
    """A parsed, validated dataset spec (format in the module docstring).

    Parameters
    ----------
    raw : dict
        The spec as read (JSON-ready); a dataset folder's identity.
    folder : Path
        Folder of the spec file: relative paths (rig file, parts) resolve against it.
    seed : int
        Base seed [-].
    samples : int
        Number of samples [-].
    name : str
        Dataset name.
    description : str
        Free text for the dataset card.
    rig : dict
        The base rig as nested tables (``rig_to_dict``), before variations and binning.
    rig_source : str
        ``"preset:NAME"`` or ``"file:PATH"`` (as written in the spec).
    scenario : dict
        Fixed scenario keys (``kind`` included).
    materials : dict
        Fixed ``MaterialSettings`` values.
    variation : dict
        ``{"rig": {...}, "scenario": {...}, "materials": {...}}``: the varied keys.
    """

    raw: dict
    folder: Path
    seed: int
    samples: int
    name: str
    description: str
    rig: dict
    rig_source: str
    scenario: dict
    materials: dict
    variation: dict = field(default_factory=dict)

    @property
    def kind(self) -> str:
        """The scenario kind: ``calibration``, ``blocker`` or ``rotary``."""
        return self.scenario["kind"]

    def sha256(self) -> str:
        """SHA-256 of the canonical JSON of :attr:`raw` (the spec's identity).

        Returns
        -------
        str
            64 hex digits.
        """
        return hashlib.sha256(json.dumps(self.raw, sort_keys=True).encode()).hexdigest()

    def input_files(self) -> list[Path]:
        """Files the spec refers to (rig file, mesh and scene files), resolved, existing only.

        Returns
        -------
        list of Path
            Sorted, without duplicates.
        """
        names = []
        if self.rig_source.startswith("file:"):
            names.append(self.rig_source[5:])
        for part in _part_candidates(self):
            if Path(part).suffix:
                names.append(part)
        paths = [self.resolve(n) for n in names]
        return sorted({p for p in paths if p.is_file()})

    def resolve(self, name: str) -> Path:
        """A path of the spec, relative to the spec's folder unless absolute.

        Parameters
        ----------
        name : str
            The path as written in the spec (``~`` expanded).

        Returns
        -------
        Path
            Absolute path.
        """
        p = Path(os.path.expanduser(name))
        return p if p.is_absolute() else (self.folder / p).resolve()


@dataclass(frozen=True)
class SamplePlan:
    """What sample k draws: everything a worker needs to make it alone.

    Parameters
    ----------
    index : int
        Sample number k [-].
    seed : int
        Sample seed (``sample_seed(base, k)``) [-].
    rig : dict
        The sample's rig (variations and binning applied) as nested tables.
    kind : str
        Scenario kind.
    options : dict
        Keyword options of the ``sim.scenarios`` builder (``part`` resolved to a path
        or preset name).
    part : str
        The part as written in the spec (preset, mesh or scene file), "" for none.
    material : str or None
        Material tag imposed on every part, None = the parts' own.
    materials : dict
        ``MaterialSettings`` keyword values.
    spp : int or None
        Laser samples per lit row, None = the renderer's default.
    truth_pixels_every : int
        Per-pixel truth every N-th frame, 0 = none.
    frames : int
        Number of frames the scenario will have [-].
    binning : int
        k × k binning of the sensor [-].
    drawn : dict
        The drawn values, ``{"rig.sensor.roll_deg": v, "scenario.part": "sphere", …}``.
    """

    index: int
    seed: int
    rig: dict
    kind: str
    options: dict
    part: str
    material: str | None
    materials: dict
    spp: int | None
    truth_pixels_every: int
    frames: int
    binning: int
    drawn: dict

    def build_rig(self) -> Rig:
        """The sample's :class:`Rig`.

        Returns
        -------
        Rig
            Built from :attr:`rig` (validated).
        """
        return rig_from_dict(self.rig)


def sample_seed(seed: int, index: int) -> int:
    """The 32-bit seed of sample ``index`` of a dataset with base seed ``seed``.

    Parameters
    ----------
    seed : int
        Base seed of the dataset (≥ 0).
    index : int
        Sample number k (≥ 0).

    Returns
    -------
    int
        ``SeedSequence((seed, index, 0xDA7A))``'s first 32-bit word.

    Raises
    ------
    ValueError
        For a negative seed or index.
    """
    if seed < 0 or index < 0:
        raise ValueError(f"seed and sample index must be >= 0, got {seed}, {index}")
    ss = np.random.SeedSequence((int(seed), int(index), _STREAM_SAMPLE))
    return int(ss.generate_state(1, np.uint32)[0])


# ------------------------------------------------------------------ parsing


def _fail(where: str, msg: str) -> DatasetError:
    return DatasetError(f"{where}: {msg}")


def load_spec(path: str | os.PathLike) -> DatasetSpec:
    """Read and validate a dataset spec file.

    Parameters
    ----------
    path : path
        The TOML spec.

    Returns
    -------
    DatasetSpec
        The validated spec.

    Raises
    ------
    DatasetError
        A missing or unreadable file, invalid TOML, an unknown key, a bad value or range.
    """
    p = Path(path)
    raw = read_toml(p, "spec file", DatasetError)
    return parse_spec(raw, folder=p.resolve().parent, where=str(p), default_name=p.stem)


def parse_spec(raw: dict, folder: str | os.PathLike = ".", where: str = "spec",
               default_name: str = "dataset") -> DatasetSpec:
    """Validate a spec given as nested tables (what :func:`load_spec` reads).

    Parameters
    ----------
    raw : dict
        The spec's tables.
    folder : path
        Folder that relative paths resolve against.
    where : str
        Name of the spec in error messages (its file name).
    default_name : str
        Dataset name when ``[dataset] name`` is not given.

    Returns
    -------
    DatasetSpec
        The validated spec.

    Raises
    ------
    DatasetError
        An unknown key, a missing required key, a bad value or variation, a part that is
        neither a preset name nor an existing file.
    """
    _known(where, "the spec", raw, _TOP)
    for table in _TOP:
        if table in raw and not isinstance(raw[table], dict):
            raise _fail(where, f"[{table}] must be a table")
    ds = raw.get("dataset", {})
    _known(where, "[dataset]", ds, _DATASET_KEYS)
    seed = _count(where, "dataset.seed", ds.get("seed", 0), minimum=0)
    samples = _count(where, "dataset.samples", ds.get("samples"), minimum=1)
    rig, rig_source, rig_var = _parse_rig(where, Path(folder), raw.get("rig", {}))
    scenario, scen_var = _parse_scenario(where, raw.get("scenario"))
    materials, mat_var = _parse_materials(where, raw.get("materials", {}))
    spec = DatasetSpec(raw=json.loads(json.dumps(raw)), folder=Path(folder), seed=seed,
                       samples=samples, name=str(ds.get("name", default_name)),
                       description=str(ds.get("description", "")), rig=rig, rig_source=rig_source,
                       scenario=scenario, materials=materials,
                       variation={"rig": rig_var, "scenario": scen_var, "materials": mat_var})
    _check_parts(spec, where)
    _check_spp(spec, where)
    return spec


def _check_spp(spec: DatasetSpec, where: str) -> None:
    """The largest laser sample count the spec can draw fits the renderer's memory (before any sample)."""
    def extreme(key, pick):
        values = [spec.scenario[key]] if key in spec.scenario else []
        if key in spec.variation["scenario"]:
            values += [v for v in _possible_values(spec.variation["scenario"][key]) if isinstance(v, (int, float))]
        return pick(values) if values else None

    spp, binning = extreme("spp", max), extreme("binning", min) or 1
    if spp is None:
        return
    rows = max(1, int(spec.rig["sensor"]["rows"]) // int(binning))
    bounces = int(spec.rig.get("twin", {}).get("bounces", 1))
    check_laser_samples(int(spp), rows, bounces, name="scenario.spp",
                        error=lambda msg: _fail(where, msg))


def _check_parts(spec: DatasetSpec, where: str) -> None:
    """Every part the spec can draw exists: a preset name, or a file that is there (before any sample)."""
    for part in _part_candidates(spec):
        if Path(part).suffix:
            if not spec.resolve(part).is_file():
                raise _fail(where, f"part {part!r}: no such file ({spec.resolve(part)})")
        elif part not in PART_NAMES:
            raise _fail(where, f"part {part!r}: unknown (a preset name — {', '.join(PART_NAMES)} — "
                               "or a mesh or scene file)")


def _known(where: str, table: str, data: dict, known: set) -> None:
    unknown = sorted(set(data) - known)
    if unknown:
        raise _fail(where, f"unknown key {unknown[0]!r} in {table} (known: {', '.join(sorted(known))})")


def _count(where: str, key: str, value, minimum: int) -> int:
    if value is None:
        raise _fail(where, f"{key} is required")
    if not isinstance(value, int) or isinstance(value, bool) or value < minimum:
        raise _fail(where, f"{key} = {value!r}: must be an integer >= {minimum}")
    return value


def _parse_rig(where: str, folder: Path, table: dict) -> tuple[dict, str, dict]:
    _known(where, "[rig]", table, _RIG_KEYS)
    if "preset" in table and "file" in table:
        raise _fail(where, "[rig]: give either preset or file, not both")
    try:
        if "file" in table:
            name = str(table["file"])
            path = Path(os.path.expanduser(name))
            rig = load_rig(path if path.is_absolute() else folder / path)
            source = f"file:{name}"
        else:
            preset = table.get("preset", "paper")
            if preset not in PRESETS:
                raise _fail(where, f"rig.preset = {preset!r}: unknown (known: {', '.join(PRESETS)})")
            rig, source = load_preset(preset), f"preset:{preset}"
    except DatasetError:
        raise
    except ScheimpflugError as exc:
        raise _fail(where, f"[rig]: {exc}") from None
    if chain_is_on(rig.chain):
        raise _fail(where, f"[rig]: [chain] format = {rig.chain.format!r}: a dataset stores 16-bit grey frames "
                           "only (set format = \"png16\"; 'scheimpflug render' writes the camera chain's files)")
    base = rig_to_dict(rig)
    variation = table.get("variation", {})
    if not isinstance(variation, dict):
        raise _fail(where, "[rig.variation] must be a table")
    for key, spec in variation.items():
        tbl, _, leaf = key.partition(".")
        if tbl not in base or leaf not in base[tbl]:
            known = ", ".join(f"{t}.{k}" for t in base for k in base[t])
            raise _fail(where, f"rig.variation: unknown rig key {key!r} (known: {known})")
        _check_variation(where, f"rig.variation.{key!r}", spec, isinstance(base[tbl][leaf], int))
    return base, source, dict(variation)


def _parse_scenario(where: str, table) -> tuple[dict, dict]:
    if not isinstance(table, dict) or "kind" not in table:
        raise _fail(where, "[scenario] kind is required (calibration | blocker | rotary)")
    kind = table["kind"]
    if kind not in _KINDS:
        raise _fail(where, f"scenario.kind = {kind!r}: unknown (known: {', '.join(_KINDS)})")
    known = _COMMON | set(_OPTIONS[kind])
    _known(where, f"[scenario] (kind {kind!r})", table, known)
    variation = table.get("variation", {})
    if not isinstance(variation, dict):
        raise _fail(where, "[scenario.variation] must be a table")
    _known(where, "[scenario.variation]", variation, known - {"kind", "variation"})
    fixed = {k: v for k, v in table.items() if k != "variation"}
    for key, value in fixed.items():
        if key != "kind":
            _check_scenario_value(where, f"scenario.{key}", key, value)
    for key, spec in variation.items():
        _check_variation(where, f"scenario.variation.{key}", spec, key in _INT_KEYS)
        for value in _possible_values(spec):
            _check_scenario_value(where, f"scenario.variation.{key}", key, value)
    if "truth_pixels" in variation:
        raise _fail(where, "scenario.variation.truth_pixels: per-pixel truth cannot vary")
    return fixed, dict(variation)


def _possible_values(spec) -> list:
    if isinstance(spec, dict) and "choices" in spec:
        return list(spec["choices"])
    if isinstance(spec, list):
        return list(spec)
    return [spec["normal"][0]] if isinstance(spec, dict) else [spec]


def _check_scenario_value(where: str, name: str, key: str, value) -> None:
    if key in ("part", "material", "truth_pixels"):
        if key == "material" and value not in _MATERIAL_TAGS:
            raise _fail(where, f"{name} = {value!r}: unknown material (known: {', '.join(_MATERIAL_TAGS)})")
        if key == "part" and (not isinstance(value, str) or not value):
            raise _fail(where, f"{name} = {value!r}: must be a preset name, mesh file or scene file")
        if key == "truth_pixels":
            _truth_every(where, value)
        return
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise _fail(where, f"{name} = {value!r}: must be a finite number")
    if key in _INT_KEYS and (not float(value).is_integer() or value < 1):
        raise _fail(where, f"{name} = {value!r}: must be an integer >= 1")
    if key == "step_deg" and not value > 0:
        raise _fail(where, f"{name} = {value!r}: the rotary step must be > 0 degrees")


def _truth_every(where: str, value) -> int:
    if value == "none":
        return 0
    if value == "every":
        return 1
    if isinstance(value, int) and not isinstance(value, bool) and value >= 1:
        return value
    raise _fail(where, f"scenario.truth_pixels = {value!r}: expected \"none\", \"every\" or an integer >= 1")


def _parse_materials(where: str, table: dict) -> tuple[dict, dict]:
    names = {f.name for f in fields(MaterialSettings)}
    _known(where, "[materials]", table, names | {"variation"})
    variation = table.get("variation", {})
    if not isinstance(variation, dict):
        raise _fail(where, "[materials.variation] must be a table")
    _known(where, "[materials.variation]", variation, names)
    fixed = {k: v for k, v in table.items() if k != "variation"}
    for key, spec in variation.items():
        _check_variation(where, f"materials.variation.{key}", spec, False)
    try:
        MaterialSettings(**fixed)
    except (TypeError, ValueError) as exc:
        raise _fail(where, f"[materials]: {exc}") from None
    return fixed, dict(variation)


def _is_num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _check_variation(where: str, name: str, spec, integer: bool) -> None:
    """Raise unless ``spec`` is [lo, hi], {choices = [...]}, {normal = [mean, sigma]} or a value."""
    if isinstance(spec, list):
        if len(spec) != 2 or not all(_is_num(v) and math.isfinite(v) for v in spec):
            raise _fail(where, f"{name} = {spec!r}: a range must be [lo, hi] with two finite numbers")
        if not spec[0] < spec[1]:
            what = "empty" if spec[0] == spec[1] else "reversed"
            raise _fail(where, f"{name} = {spec!r}: the range is {what} (need lo < hi; "
                               "give a plain value to fix a key)")
        if integer and not all(float(v).is_integer() for v in spec):
            raise _fail(where, f"{name} = {spec!r}: an integer key needs integer bounds")
        return
    if isinstance(spec, dict):
        if set(spec) == {"choices"}:
            if not isinstance(spec["choices"], list) or not spec["choices"]:
                raise _fail(where, f"{name}: choices must be a non-empty list")
            return
        if set(spec) == {"normal"}:
            ms = spec["normal"]
            if not (isinstance(ms, list) and len(ms) == 2 and all(_is_num(v) for v in ms)
                    and math.isfinite(ms[0]) and math.isfinite(ms[1]) and ms[1] > 0):
                raise _fail(where, f"{name} = {spec!r}: normal needs [mean, sigma] with sigma > 0")
            if integer:
                raise _fail(where, f"{name}: an integer key cannot be drawn from a normal distribution")
            return
        raise _fail(where, f"{name} = {spec!r}: a table must be {{ choices = [...] }} or "
                           "{ normal = [mean, sigma] }")
    if not (_is_num(spec) or isinstance(spec, str)):
        raise _fail(where, f"{name} = {spec!r}: expected [lo, hi], {{ choices = [...] }}, "
                           "{ normal = [mean, sigma] } or a value")


# ------------------------------------------------------------------ drawing


def _draw(spec, rng: np.random.Generator, integer: bool):
    """One value of a (validated) variation."""
    if isinstance(spec, list):
        if integer:
            return int(rng.integers(int(spec[0]), int(spec[1]) + 1))
        return float(rng.uniform(float(spec[0]), float(spec[1])))
    if isinstance(spec, dict) and "choices" in spec:
        return spec["choices"][int(rng.integers(len(spec["choices"])))]
    if isinstance(spec, dict):
        mean, sigma = spec["normal"]
        return float(rng.normal(float(mean), float(sigma)))
    return spec


def _key_rng(seed: int, index: int, key: str) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence((int(seed), int(index), zlib.crc32(key.encode()))))


def _draw_section(spec: DatasetSpec, k: int, section: str, integer_keys) -> dict:
    out = {}
    for key in sorted(spec.variation[section]):
        rng = _key_rng(spec.seed, k, f"{section}.{key}")
        out[key] = _draw(spec.variation[section][key], rng, key in integer_keys)
    return out


def _scenario_defaults(kind: str) -> dict:
    from .. import scenarios

    fn = {"calibration": scenarios.calibration_scenario, "blocker": scenarios.blocker_scenario,
          "rotary": scenarios.rotary_scenario}[kind]
    return {k: p.default for k, p in inspect.signature(fn).parameters.items()
            if p.default is not inspect.Parameter.empty}


def planned_frames(kind: str, options: dict) -> int:
    """Number of frames the scenario ``kind`` with ``options`` will have (sim.scenarios' rules).

    Parameters
    ----------
    kind : str
        Scenario kind.
    options : dict
        Its keyword options (defaults from the ``sim.scenarios`` builders).

    Returns
    -------
    int
        Frame count [-].
    """
    opts = {**_scenario_defaults(kind), **options}
    if kind == "calibration":
        return int(opts["steps"])
    if kind == "blocker":
        return int(opts["frames"])
    n_turn = max(1, int(round(360.0 / float(opts["step_deg"]))))
    return n_turn if opts.get("frames") is None else min(n_turn, int(opts["frames"]))


def _candidates(spec: DatasetSpec, key: str) -> list[float]:
    """The values a scenario key can take in any sample: fixed, range ends, choices, mean ± 4 sigma."""
    var = spec.variation["scenario"].get(key)
    if var is None:
        return [spec.scenario[key]] if key in spec.scenario else []
    if isinstance(var, dict) and "normal" in var:
        mu, sigma = var["normal"]
        return [mu - 4 * sigma, mu + 4 * sigma]
    return [v for v in _possible_values(var) if _is_num(v)]


def frames_bound(spec: DatasetSpec) -> tuple[int, str]:
    """The most frames one sample of ``spec`` can have, from the spec alone (nothing is drawn).

    Parameters
    ----------
    spec : DatasetSpec
        The dataset spec.

    Returns
    -------
    frames : int
        Upper bound of any sample's frame count [-] (the largest ``steps`` or ``frames``, the
        smallest ``step_deg`` the spec allows).
    why : str
        The keys that set it, e.g. ``"scenario.step_deg = 1e-09"``.
    """
    kind = spec.scenario["kind"]
    defaults = _scenario_defaults(kind)
    if kind in ("calibration", "blocker"):
        key = "steps" if kind == "calibration" else "frames"
        values = _candidates(spec, key) or [defaults[key]]
        return int(max(values)), f"scenario.{key} = {max(values):g}"
    steps = [v for v in _candidates(spec, "step_deg") or [defaults["step_deg"]] if v > 0]
    step = min(steps) if steps else 360.0
    n_turn = max(1, int(round(360.0 / step))) if 360.0 / step < 1e18 else 10**18
    caps = _candidates(spec, "frames")
    if caps and max(caps) < n_turn:
        return int(max(caps)), f"scenario.frames = {max(caps):g}"
    return n_turn, f"scenario.step_deg = {step:g}"


def plan_sample(spec: DatasetSpec, k: int) -> SamplePlan:
    """Draw sample ``k`` of ``spec``: its seed, rig, scenario options and materials.

    Parameters
    ----------
    spec : DatasetSpec
        The dataset spec.
    k : int
        Sample number, 0 ≤ k < ``spec.samples``.

    Returns
    -------
    SamplePlan
        Everything a worker needs to make the sample.

    Raises
    ------
    DatasetError
        When the drawn values make an impossible rig or scenario (naming the sample).
    """
    rig_draw = _draw_section(spec, k, "rig", _int_rig_keys(spec.rig))
    scen_draw = _draw_section(spec, k, "scenario", _INT_KEYS)
    mat_draw = _draw_section(spec, k, "materials", ())
    scen = {**spec.scenario, **scen_draw}
    kind = scen["kind"]
    binning = int(scen.get("binning", 1))
    tables = json.loads(json.dumps(spec.rig))
    for key, value in rig_draw.items():
        tbl, _, leaf = key.partition(".")
        tables[tbl][leaf] = value
    try:
        rig = binned_rig(rig_from_dict(tables), binning)
    except (ScheimpflugError, ValueError) as exc:
        raise DatasetError(f"sample {k}: the drawn rig is impossible: {exc}") from None
    options = {_OPTIONS[kind][key]: value for key, value in scen.items() if key in _OPTIONS[kind]}
    for key in _INT_KEYS & set(options):
        options[key] = int(options[key])
    part = str(scen.get("part", "")) if kind == "rotary" else ""
    if part and Path(part).suffix:
        options["part"] = str(spec.resolve(part))
    drawn = {**{f"rig.{k_}": v for k_, v in rig_draw.items()},
             **{f"scenario.{k_}": v for k_, v in scen_draw.items()},
             **{f"materials.{k_}": v for k_, v in mat_draw.items()}}
    return SamplePlan(index=k, seed=sample_seed(spec.seed, k), rig=rig_to_dict(rig), kind=kind,
                      options=options, part=part or ("plate" if kind == "calibration" else
                                                      "blocker" if kind == "blocker" else ""),
                      material=scen.get("material"), materials={**spec.materials, **mat_draw},
                      spp=int(scen["spp"]) if "spp" in scen else None,
                      truth_pixels_every=_truth_every("spec", scen.get("truth_pixels", "none")),
                      frames=planned_frames(kind, options), binning=binning, drawn=drawn)


def _int_rig_keys(rig: dict) -> set:
    return {f"{t}.{k}" for t, table in rig.items() for k, v in table.items() if isinstance(v, int)}


def _part_candidates(spec: DatasetSpec) -> list[str]:
    parts = []
    if "part" in spec.scenario:
        parts.append(str(spec.scenario["part"]))
    var = spec.variation["scenario"].get("part")
    if var is not None:
        parts += [str(v) for v in _possible_values(var)]
    return parts
