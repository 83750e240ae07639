"""How many laser samples a frame can take: the memory of the light tracer's laser pass, measured.

The laser pass (:mod:`sim.render`) shoots N = ``samples_per_row`` · rows samples
per frame at once, as Dr.Jit arrays (no batching): its memory grows with N, and
Dr.Jit refuses an array of more than 2³² entries with a raw ``RuntimeError``
after having allocated for minutes.  Measured peak memory per sample (``/usr/bin/time``
maximum resident set of ``scheimpflug render calibration --binning 8 --steps 1
--truth-pixels none``, 242 rows, ``--spp`` 10⁵ … 10⁶, minus the 0.32 GB of a
1000-spp run; docs/tutorials/render-and-calibrate.md): ≈ 20.5 B with one bounce (the ideal twin; the same
with ``--subsurface`` on the cardboard plate) and ≈ 206–209 B with two or more
(``--bounces 2``, ``--bounces 8`` and the paper-as-built rig's 3 give the same: the
path state of the bounces dominates).  A frame may use :data:`LASER_MEMORY_BUDGET_BYTES`
for its laser samples: at full paper size (1936 rows) that is ``spp`` ≤ 196 772 with one
bounce and ≤ 19 677 with more (the default is 32).
"""

from __future__ import annotations

import math

from scheimpflug.errors import RenderError

__all__ = ["LASER_MEMORY_BUDGET_BYTES", "SAMPLE_BYTES_MULTI_BOUNCE", "SAMPLE_BYTES_ONE_BOUNCE",
           "check_laser_samples", "laser_memory_bytes", "max_samples_per_row"]

#: Peak memory per laser sample of a first-surface (one-bounce) render, measured ≈ 20.5 B [B].
SAMPLE_BYTES_ONE_BOUNCE = 21
#: Peak memory per laser sample when the laser follows inter-reflections (bounces ≥ 2), ≈ 206–209 B [B].
SAMPLE_BYTES_MULTI_BOUNCE = 210
#: Memory one frame's laser pass may take [B] (far below Dr.Jit's 2³²-entry array limit).
LASER_MEMORY_BUDGET_BYTES = 8_000_000_000


def _per_sample(bounces: int) -> int:
    return SAMPLE_BYTES_ONE_BOUNCE if bounces <= 1 else SAMPLE_BYTES_MULTI_BOUNCE


def laser_memory_bytes(samples_per_row: int, rows: int, bounces: int = 1) -> int:
    """Peak memory of one frame's laser pass (module docstring) [B].

    Parameters
    ----------
    samples_per_row : int
        Laser samples per sensor row (``--spp``) [-].
    rows : int
        Sensor rows rendered (binned) [-].
    bounces : int
        Light-path depth of the laser (rig key ``[twin] bounces``) [-].

    Returns
    -------
    int
        samples_per_row · rows · bytes per sample [B].
    """
    return int(samples_per_row) * int(rows) * _per_sample(bounces)


def max_samples_per_row(rows: int, bounces: int = 1) -> int:
    """The largest ``spp`` whose laser pass fits :data:`LASER_MEMORY_BUDGET_BYTES`.

    Parameters
    ----------
    rows : int
        Sensor rows rendered (binned) [-].
    bounces : int
        Light-path depth of the laser [-].

    Returns
    -------
    int
        Laser samples per row allowed [-].
    """
    return LASER_MEMORY_BUDGET_BYTES // (max(int(rows), 1) * _per_sample(bounces))


def check_laser_samples(samples_per_row: int, rows: int, bounces: int = 1, name: str = "spp",
                        error: type[Exception] = RenderError) -> None:
    """Refuse a sample count whose laser pass would not fit the memory budget, in one line.

    Parameters
    ----------
    samples_per_row : int
        Laser samples per sensor row [-].
    rows : int
        Sensor rows rendered (binned) [-].
    bounces : int
        Light-path depth of the laser [-].
    name : str
        How the caller calls the setting in the message (``--spp``, ``artefacts.spp``).
    error : type
        The exception raised.

    Raises
    ------
    error
        When ``samples_per_row`` · rows samples need more than :data:`LASER_MEMORY_BUDGET_BYTES`;
        the message gives the samples, the memory, the limit and the largest ``spp`` allowed.
    """
    need = laser_memory_bytes(samples_per_row, rows, bounces)
    if need <= LASER_MEMORY_BUDGET_BYTES:
        return
    per = _per_sample(bounces)
    depth = "1 bounce" if bounces <= 1 else f"{bounces} bounces"
    eq = " " if name.startswith("--") else " = "
    raise error(f"{name}{eq}{samples_per_row}: {samples_per_row} laser samples per row × {rows} rows = "
                f"{samples_per_row * rows:.3g} samples per frame would need about {_gb(need)} of memory "
                f"(≈ {per} B per sample with {depth}, measured); the limit is {_gb(LASER_MEMORY_BUDGET_BYTES)} "
                f"per frame: at most {name}{eq}{max_samples_per_row(rows, bounces):,} for {rows} rows with {depth}")


def _gb(n: float) -> str:
    return f"{n / 1e9:.3g} GB" if n < 1e12 else f"{n / 1e12:.3g} TB" if math.isfinite(n) else "∞"
