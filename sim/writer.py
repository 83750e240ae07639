"""The frame folder of docs/reference/interface.md: render a scenario frame by frame, resumable.

Layout::

    DIR/manifest.json        rig, scenario, parameters, one entry per frame (below)
    DIR/frames/NNNNN.png     16-bit grayscale PNG, raw ADC value (not shifted; see adc_bits)
                             — or, with the camera chain on ([chain] format, sim/chain.py), the
                             camera's own file: NNNNN.jpg (RGB JPEG) or NNNNN.png (8-bit RGB)
    DIR/truth/NNNNN.npz      per-frame truth (format: sim.truth module docstring)
    DIR/truth/mesh.ply       the scene in the truth reference frame (object_id per face)
    DIR/truth/mesh_NNNNN.ply calibration only: the plate at frame NNNNN's stage position
    DIR/truth/rig_truth.json closed-form u_h, v_h, F², C, d0, axis of the rig (sim.truth.rig_truth)
    DIR/truth/sensor_maps.npz the sensor's fixed-pattern maps when on: prnu_gain [-], dark_e [e⁻]
    DIR/checksums.jsonl      size and SHA-256 of each finished frame's PNG and truth file
    DIR/.scheimpflug.lock    while a run writes the folder: its pid, host, start, program

``manifest.json`` keys: ``format``, ``complete`` (false while rendering),
``rig`` (rig_to_dict), ``scenario``, ``scenario_params``, ``seed``, ``render``
({"spp", "variant", "settings": all RenderSettings}), ``adc_bits``, ``pixel_value`` (how DN are stored),
``truth`` (format description, reference frame, which frames have per-pixel
maps), ``generator`` (program and library versions) and ``frames``:
``[{"file": "frames/00000.png", "truth": "truth/00000.npz", "stage_mm": s |
"angle_deg": θ, "exposure_ms": ..., "seed": ..., "pixel_truth": bool}, ...]``;
``stage_mm`` / ``angle_deg`` and ``exposure_ms`` are the commanded values.  When
the rig has error models on (:func:`scheimpflug.model.rig.active_error_models`),
each frame also has ``actual``: what the erring instrument really did
(``stage`` — for the translation stage ``stage_mm``, ``position_error_um``,
``lateral_um``, ``vertical_um``, ``pitch_urad``, ``yaw_urad``; for the rotary
stage ``angle_deg``, ``angle_error_deg``, ``wobble_urad``, ``radial_um`` —,
``exposure_factor``, ``pointing_urad`` [about e_z, about e_p],
``lens_centre_x_mm``).
When finished it also lists ``frames_without_stripe``.

One writer at a time: a run holds ``DIR/.scheimpflug.lock`` (pid, host, start,
program; :class:`scheimpflug.io.folder.FolderLock`) from start to end; a second
run into the same folder is refused with :class:`RenderError` naming the owner,
and a lock left by a killed run is taken over with a warning.

Restart: the manifest is written first (``"complete": false``) listing every
frame, and rewritten with ``"complete": true`` at the end.  A frame is complete
when both its truth file and its PNG exist (each is written atomically, truth
first) and match the size and SHA-256 recorded for them in ``DIR/checksums.jsonl``
when they were written (:class:`scheimpflug.io.folder.FileLedger`).  Rendering into
a folder that already has a manifest resumes it — frames already complete are
skipped, a frame whose files are missing, truncated, altered or were never
recorded is rendered again (with a warning) — if, and only if, the manifest
describes the same run (same rig, scenario, parameters, seed, render settings,
variant and frames); otherwise :class:`RenderError` names the first difference.
A non-empty folder without a manifest is refused.  A write that fails (a full
disk) raises :class:`RenderError` naming the folder; nothing is half-written
and the run resumes.

The frame loop's steps are shared with the worker pool of :mod:`sim.workers`
(one folder protocol, two ways to render it): :func:`run_locked`,
:func:`render_locked`, :func:`build_run`, :func:`scene_arrays`, :func:`frame_products`,
:func:`frame_file_names`, :func:`describe_frame` and :func:`index_ranges` are that
shared part — public to the package, not in ``__all__``.
"""

from __future__ import annotations

import io
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np

from scheimpflug.callbacks import ProgressCallback, report
from scheimpflug.errors import RenderError
from scheimpflug.io.atomic import atomic_path, write_json_atomic
from scheimpflug.io.folder import LEDGER_NAME, LOCK_NAME, FileLedger
from scheimpflug.model.camera import stripe_along
from scheimpflug.model.chain import chain_is_on
from scheimpflug.model.rig import Rig, is_realistic, rig_to_dict

from .backgrounds import background_poses
from .camera_pass import camera_pass_of, uses_camera_pass
from .chain import ChainModel, apply_chain, encode_frame, frame_suffix
from .jobfolder import JobKind, check_identity, create_folder, open_job, remove_temporaries
from .materials import MaterialSettings
from .scenarios import FrameSpec, Scenario
from .sensor import SensorModel, apply_sensor, frame_rng
from .stages import invert
from .threads import drjit_threads
from .truth import (
    RayCaster,
    SceneTruth,
    pixel_directions,
    pixel_truth,
    rig_truth,
    secondary_truth,
)

__all__ = [
    "FORMAT",
    "MitsubaTwin",
    "PNG_COMPRESSION",
    "RenderStats",
    "Twin",
    "JobEstimate",
    "build_manifest",
    "encode_npz",
    "encode_png16",
    "estimate_job",
    "frame_model",
    "frame_paths",
    "generator_info",
    "prepare_folder",
    "read_png",
    "render_folder",
    "render_scenario",
    "write_frame_file",
    "write_png",
]

FORMAT = "scheimpflug-frames/1"
#: zlib level of the 16-bit PNGs (:func:`encode_png16`: filter "none", one zlib stream).
#: Measured on a full paper frame of the cylinder scan: this encoder at level 1 ≈ 42 ms /
#: 1.18 MB; OpenCV's imwrite at level 1 ≈ 66 ms / 1.26 MB (Huffman-only ≈ 59 ms / 1.11 MB),
#: level 3 ≈ 124 ms / 1.15 MB, level 0 ≈ 32 ms / 4.7 MB (benchmarks/bench_scan.py prints
#: the comparison).  Noise-dominated frames gain little from filters or higher levels.
PNG_COMPRESSION = 1
#: the manifest's description of a target frame's pattern truth (sim.target)
TARGET_TRUTH = ("truth/NNNNN.npz also holds pattern_corners_px (n, 2) f64 [px] (chief ray; NaN = off the "
                "sensor, facing away or hidden), pattern_corner_ids (n, 2) i64 (column, row), pattern_centroid_px "
                "(n, 2) f64 [px] (light centroid of the corner's blur spot), pattern_blur_px (n,) f64 [px], "
                "rig_from_pattern and camera_from_pattern (4, 4) f64 [mm] (camera: truth/rig_truth.json opencv); "
                "flood frames have no stripe. See sim/target.py.")
_IDENTITY_KEYS = ("format", "rig", "scenario", "scenario_params", "seed", "render", "frames")
#: the frame folder as a job (:mod:`sim.jobfolder`): its manifest is its identity
FRAME_FOLDER = JobKind(
    error=RenderError, meta_file="manifest.json", noun="run", folder_noun="frame folder",
    differs="output folder {out!r} holds a different run ({where!r} differs from this command's); "
            "choose another --out or delete the folder to start over",
    unreadable="{meta!r} exists but cannot be read ({exc}); remove the folder or choose another --out",
    depth=1, subset_keys=(), own_files=(LOCK_NAME, LEDGER_NAME), own_dirs=("frames", "truth"))


class Twin(Protocol):
    """What the frame loop needs from the renderer (:class:`MitsubaTwin`, or a test double).

    A structural type (:class:`typing.Protocol`): any object with matching
    :meth:`render` and :meth:`caster` methods is a twin.  A twin may also have
    ``begin(frame)`` returning a :class:`sim.render.PendingLight` whose ``finish()``
    is ``render(frame)``'s image without further scene queries
    (:meth:`MitsubaTwin.begin`); the pipelined loop then finishes frames on another
    thread.

    Parameters
    ----------
    *args, **kwargs
        None: a protocol is a type to implement, not a class to instantiate.
    """

    def render(self, frame: FrameSpec) -> np.ndarray:
        """Expected photo-electrons of the scene posed for a frame.

        Parameters
        ----------
        frame : FrameSpec
            The frame (pose of the parts, seed).

        Returns
        -------
        (rows, columns) float32
            Expected electrons per pixel [e⁻], before sensor noise.
        """

    def caster(self, frame: FrameSpec) -> RayCaster:
        """First-hit ray queries for the scene posed for a frame.

        Parameters
        ----------
        frame : FrameSpec
            The frame (pose of the parts).

        Returns
        -------
        RayCaster
            Queries in the rig frame [mm].
        """


def _twin_light(twin, frame: FrameSpec):
    """The twin's light split of ``frame`` (:class:`sim.render.FrameLight`) if it keeps one."""
    light = getattr(twin, "light", None)
    return light(frame) if callable(light) else None


#: RenderSettings field that ``--spp`` sets (the light tracer's laser samples per sensor row).
_SPP_FIELDS = ("samples_per_row", "samples_per_fan_ray", "spp")


class MitsubaTwin:
    """The Mitsuba digital twin behind the frame loop.

    A :class:`sim.scene.SimScene` and a :class:`sim.render.Renderer`, one scene
    for the whole run (posed per frame).  Implements :class:`Twin`.

    Parameters
    ----------
    rig : Rig
        The rig.
    assembly : scenes.Assembly
        The parts, in the part frame.
    spp : int or None, optional
        Laser samples of the light tracer (``RenderSettings.samples_per_row``: splats per
        lit sensor row); None = the renderer's default.
    settings : sim.render.RenderSettings, optional
        Render settings; ``spp`` overrides its samples.
    materials : sim.materials.MaterialSettings, optional
        Albedos and roughnesses of the material tags (default: MaterialSettings()).
    background : tuple of scenes.Part, default ()
        Parts fixed in the stage frame (a scan's walls, :mod:`sim.backgrounds`), posed by
        ``rig_from_stage`` in every frame, or turning with the table (a tilted disc,
        :func:`sim.backgrounds.background_poses`).

    Attributes
    ----------
    scene : SimScene
        The Mitsuba scene.
    renderer : Renderer
        The renderer.
    settings : RenderSettings
        The settings in use (with ``spp`` applied).
    variant : str
        The Mitsuba variant in use.
    spp : int
        Laser samples per lit sensor row in use.

    Raises
    ------
    RenderError
        When no JIT variant of Mitsuba (``llvm_*``/``cuda_*``) is usable.
    MeshError
        For an invalid part mesh or material.
    """

    def __init__(self, rig: Rig, assembly, spp: int | None = None, settings=None,
                 materials=None, background=()) -> None:
        import dataclasses

        from .render import Renderer, RenderSettings
        from .scene import SimScene
        from .variant import is_jit_variant, select_variant

        variant = select_variant()
        if not is_jit_variant(variant):
            raise RenderError(
                f"the renderer needs one of Mitsuba's JIT variants (llvm_* or cuda_*), but only "
                f"{variant!r} is usable here: install a libLLVM >= 17 (Debian 12: 'apt-get install "
                "libllvm19', which 'bash run.sh' does as root) or set DRJIT_LIBLLVM_PATH")
        settings = settings or RenderSettings()
        field_names = {f.name for f in dataclasses.fields(settings)}
        self.spp_field = next(n for n in _SPP_FIELDS if n in field_names)
        if spp is not None:
            settings = dataclasses.replace(settings, **{self.spp_field: int(spp)})
        self.scene = SimScene([*assembly.parts, *background], materials=materials, subsurface=rig.twin.subsurface)
        self._moving, self._static = len(assembly.parts), len(background)
        self._exposure_ms = rig.sensor.exposure_ms        # the laser pass's (sim.render: electrons per watt)
        self._background_poses = background_poses(rig, background) if background else None
        self.materials = materials
        self.camera = None      # the camera pass (sim.camera_pass) replaces the coarse ambient pass
        if uses_camera_pass(rig):
            settings = dataclasses.replace(settings, ambient=False)
            self.camera = camera_pass_of(rig, self.scene, settings.pixel_filter)
        self.renderer = Renderer(rig, self.scene, settings)
        self.settings = settings
        self.variant = self.scene.variant
        self.spp = int(getattr(settings, self.spp_field))
        self._posed = None
        self._light = (None, None)
        self._split = (None, None, None)

    def describe(self) -> dict:
        """Render description for the manifest (part of a run's identity).

        Returns
        -------
        dict
            JSON-ready: ``spp``, ``spp_means`` (the settings field it sets),
            ``variant`` and ``settings`` (every RenderSettings field).
        """
        import dataclasses

        out = {"spp": self.spp, "spp_means": f"RenderSettings.{self.spp_field}",
               "variant": self.variant, "settings": dataclasses.asdict(self.settings)}
        if self.materials is not None:
            out["materials"] = dataclasses.asdict(self.materials)
        if self.camera is not None:
            out["camera_pass"] = dataclasses.asdict(self.camera.settings)
        return out

    def render(self, frame: FrameSpec) -> np.ndarray:
        """Expected electrons of a frame; poses the scene for it.

        Parameters
        ----------
        frame : FrameSpec
            The frame (``rig_from_part``, ``seed``).

        Returns
        -------
        (rows, columns) float32
            Expected electrons per pixel [e⁻] (:meth:`Renderer.render_light`).
        """
        return self.begin(frame).finish().image

    def begin(self, frame: FrameSpec):
        """:meth:`render` up to what needs the posed scene (:meth:`sim.render.Renderer.begin_light`).

        Parameters
        ----------
        frame : FrameSpec
            The frame (``rig_from_part``, ``seed``).

        Returns
        -------
        sim.render.PendingLight
            The frame's light split (what :meth:`light` returns from now on) and, in
            ``finish()``, what is left of its image: numba on arrays, no scene query, so
            it may run on another thread while the next frame is posed.
        """
        from .render import PendingLight

        if self.camera is not None:
            self._render_with_camera(frame)
            return PendingLight(self._light[1])
        pending = self.renderer.begin_light(self._poses(frame), frame.seed, frame.rig_from_laser)
        self._posed = frame.index
        self._light = (frame.index, pending.light)
        return pending

    def _poses(self, frame: FrameSpec):
        """The scene's pose for a frame: the part's, or one per part with the background's (its own rule)."""
        if not self._static:
            return frame.rig_from_part
        return np.stack([frame.rig_from_part] * self._moving + self._background_poses(frame.rig_from_part))

    def _render_with_camera(self, frame: FrameSpec) -> np.ndarray:
        """The camera pass's image (flood light, environment) plus the laser's unless the frame is flood-lit only."""
        from .render import FrameLight

        seed = frame.seed if getattr(frame, "camera_seed", None) is None else frame.camera_seed
        flood = self.camera.render(self._poses(frame), seed, flood_scale=frame.flood_scale,
                                   exposure_ms=frame.exposure_ms)
        light = FrameLight(flood) if frame.light == "flood" else \
            self.renderer.render_light(self._poses(frame), frame.seed, frame.rig_from_laser)
        laser = np.zeros_like(flood) if frame.light == "flood" else None
        if frame.light != "flood":
            _expose(light, frame.exposure_ms, self._exposure_ms)
            laser = light.image
            light.image = light.image + flood
        self._split = (frame.index, laser, flood)
        self._posed = frame.index
        self._light = (frame.index, light)
        return light.image

    def light_split(self, frame: FrameSpec):
        """The laser's and the other light of ``frame`` apart, when the camera pass rendered it last.

        Parameters
        ----------
        frame : FrameSpec
            The frame.

        Returns
        -------
        tuple of (rows, columns) float32, or None
            (laser, flood light and environment) [e⁻]; None without a camera pass (the
            coarse ambient light is not apart from the laser's) or if another frame was
            rendered since.
        """
        index, laser, other = self._split
        return (laser, other) if index == frame.index else None

    def light(self, frame: FrameSpec):
        """The light split (:class:`sim.render.FrameLight`) of ``frame`` if it was the last rendered.

        Parameters
        ----------
        frame : FrameSpec
            The frame.

        Returns
        -------
        FrameLight or None
            None if another frame was rendered since.
        """
        index, light = self._light
        return light if index == frame.index else None

    def caster(self, frame: FrameSpec) -> RayCaster:
        """Ray queries on the scene posed for a frame.

        Poses the scene only if the last frame rendered or posed was another one.

        Parameters
        ----------
        frame : FrameSpec
            The frame (``rig_from_part``).

        Returns
        -------
        SceneCaster
            First-hit queries in the rig frame [mm].
        """
        from .truth import SceneCaster

        if self._posed != frame.index:
            self.scene.set_pose(self._poses(frame))
            self._posed = frame.index
        return SceneCaster(self.scene)


# ------------------------------------------------------------------ files


def _expose(light, exposure_ms: float | None, rendered_ms: float) -> None:
    """The laser's light of a frame exposed for ``exposure_ms`` instead of the rig's, in place.

    The laser pass counts electrons over the rig's exposure (:class:`sim.render.Renderer`); a frame
    commanded to another exposure (a room-light target's laser frame at its flood frame's) gets
    its laser light scaled as the camera pass's flood light is: one exposure for the whole frame.
    """
    if exposure_ms is None or exposure_ms == rendered_ms:
        return
    k = float(exposure_ms) / float(rendered_ms)
    for name in ("image", "laser", "coherent", "secondary", "subsurface"):
        value = getattr(light, name)
        if value is not None:
            setattr(light, name, value * np.float32(k))


def frame_paths(out: Path, index: int, suffix: str = ".png") -> tuple[Path, Path]:
    """Paths of one frame's files in a frame folder.

    Parameters
    ----------
    out : pathlib.Path
        The frame folder.
    index : int
        Frame index.
    suffix : str, default ".png"
        The frame file's suffix (``.jpg`` for the camera chain's JPEG: :func:`sim.chain.frame_suffix`).

    Returns
    -------
    png : pathlib.Path
        ``out/frames/NNNNN.png`` (or the suffix given).
    truth : pathlib.Path
        ``out/truth/NNNNN.npz``.
    """
    return out / "frames" / f"{index:05d}{suffix}", out / "truth" / f"{index:05d}.npz"


def _folder_suffix(manifest: dict) -> str:
    """The suffix of a frame folder's frame files, from its manifest's file names."""
    return ".jpg" if any(e["file"].endswith(".jpg") for e in manifest["frames"]) else ".png"


def write_frame_file(path, image: np.ndarray, model) -> None:
    """Write a frame as its camera writes it, atomically: 16-bit grey PNG, or the camera chain's file.

    Parameters
    ----------
    path : str or pathlib.Path
        Destination file (written to a temporary name, then renamed).
    image : (rows, columns) uint16 or (rows, columns, 3) uint8
        Raw ADC codes (:class:`sim.sensor.SensorModel`) or the chain's RGB frame [DN].
    model : SensorModel or ChainModel
        What made the image; a :class:`sim.chain.ChainModel` writes JPEG or 8-bit RGB PNG.

    Raises
    ------
    RenderError
        When the file cannot be written.
    """
    if not isinstance(model, ChainModel):
        write_png(path, image)
        return
    data = encode_frame(image, model.chain)
    try:
        with atomic_path(path) as tmp:
            tmp.write_bytes(data)
    except OSError as exc:
        raise RenderError(f"cannot write frame {str(path)!r}: {exc.strerror or exc}") from None


try:  # libdeflate: a faster deflate than zlib, same format
    import deflate as _libdeflate
except ImportError:  # pragma: no cover - optional speed-up
    _libdeflate = None


def _deflate_parallel(raw: memoryview, level: int, parts: int) -> bytes:
    """One zlib stream of ``raw`` compressed in ``parts`` slices on threads.

    Each slice is a raw deflate stream ended by a sync flush (the last by the
    final block), so their concatenation is one valid deflate stream (as pigz
    does); zlib releases the GIL while compressing.  The slices do not share a
    dictionary, which costs a few hundred bytes.
    """
    import zlib
    from concurrent.futures import ThreadPoolExecutor

    n = len(raw)
    cuts = [n * k // parts for k in range(parts + 1)]

    def one(k: int) -> bytes:
        c = zlib.compressobj(level, zlib.DEFLATED, -15)
        flush = zlib.Z_FINISH if k == parts - 1 else zlib.Z_SYNC_FLUSH
        return c.compress(raw[cuts[k]:cuts[k + 1]]) + c.flush(flush)

    with ThreadPoolExecutor(max_workers=parts) as pool:
        body = b"".join(pool.map(one, range(parts)))
    header = b"\x78\x01"  # deflate, 32 KiB window, no preset dictionary (31 | 0x7801)
    return header + body + (zlib.adler32(raw) & 0xFFFFFFFF).to_bytes(4, "big")


def encode_png16(image: np.ndarray, compression: int = PNG_COMPRESSION, parts: int = 2) -> bytes:
    """Encode an image as 16-bit grayscale PNG bytes (ISO/IEC 15948).

    Filter type 0 (none) on every row and one zlib stream at ``compression``:
    on noise-dominated frames the PNG filters and zlib levels > 1 buy little
    size for a lot of time (see :data:`PNG_COMPRESSION`).  The stream comes
    from libdeflate (the ``deflate`` package: 17 ms and 0.97 MB for a full
    noisy frame at level 1, against zlib's 42 ms and 1.05 MB) for levels
    1–12; without it, from zlib in ``parts`` slices on threads for images
    over 1 MiB, else from one zlib call.

    Parameters
    ----------
    image : (rows, columns) uint16
        The image [DN].
    compression : int, default PNG_COMPRESSION
        zlib/libdeflate level.
    parts : int, default 2
        Slices compressed in parallel when zlib is used (1 = one stream).

    Returns
    -------
    bytes
        The PNG file's content (IHDR, one IDAT, IEND).

    Raises
    ------
    ValueError
        When ``image`` is not a 2-D uint16 array.
    """
    import struct
    import zlib

    if image.dtype != np.uint16 or image.ndim != 2:
        raise ValueError(f"a frame must be a 2-D uint16 array, got {image.dtype} {image.shape}")
    rows, cols = image.shape
    raw = np.empty((rows, 2 * cols + 1), dtype=np.uint8)
    raw[:, 0] = 0                                                   # filter: none
    raw[:, 1:].view(">u2")[...] = image                           # big-endian, in one pass
    data = memoryview(raw).cast("B")
    if _libdeflate is not None and 1 <= compression <= 12:
        idat = _libdeflate.zlib_compress(data, int(compression))
    elif parts > 1 and raw.nbytes > (1 << 20):
        idat = _deflate_parallel(data, int(compression), parts)
    else:
        idat = zlib.compress(data, int(compression))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data \
            + struct.pack(">I", zlib.crc32(data, zlib.crc32(kind)) & 0xFFFFFFFF)

    header = struct.pack(">IIBBBBB", cols, rows, 16, 0, 0, 0, 0)   # 16-bit grayscale
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", idat) \
        + chunk(b"IEND", b"")


def write_png(path, image: np.ndarray, compression: int = PNG_COMPRESSION) -> None:
    """Write an image as a 16-bit grayscale PNG, atomically.

    Parameters
    ----------
    path : str or pathlib.Path
        Destination file (written to a temporary name, then renamed).
    image : (rows, columns) uint16
        The image [DN].
    compression : int, default PNG_COMPRESSION
        zlib/libdeflate level (:func:`encode_png16`).

    Raises
    ------
    RenderError
        When the file cannot be written.
    ValueError
        When ``image`` is not a 2-D uint16 array.
    """
    data = encode_png16(image, compression)
    try:
        with atomic_path(path) as tmp:
            tmp.write_bytes(data)
    except OSError as exc:
        raise RenderError(f"cannot write frame {str(path)!r}: {exc.strerror or exc}") from None


def read_png(path) -> np.ndarray:
    """Read a 16-bit grayscale PNG.

    Parameters
    ----------
    path : str or pathlib.Path
        The PNG file.

    Returns
    -------
    (rows, columns) uint16
        The image as stored [DN] (OpenCV, unchanged depth).

    Raises
    ------
    RenderError
        When the file cannot be read or decoded.
    """
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise RenderError(f"cannot read frame {str(path)!r}")
    return img


def encode_npz(arrays: dict) -> bytes:
    """A compressed, byte-reproducible ``.npz`` (read with ``np.load``).

    What ``np.savez_compressed`` writes, each member deflated at level 1: by
    libdeflate when it is installed (the per-pixel maps of a full frame, 33 MB:
    0.24 s and 23 MB, against zlib's 0.62 s and 21 MB), else by zlib through
    :mod:`zipfile`.  Every member carries the same fixed time stamp
    (1980-01-01), so the same arrays always give the same bytes
    (``np.savez_compressed`` stamps the current time) and the same SHA-256 in the
    folder's ledger.

    Parameters
    ----------
    arrays : dict
        Name → array (``name.npy`` in the archive).

    Returns
    -------
    bytes
        The archive.
    """
    members = []
    for key, value in arrays.items():
        member = io.BytesIO()
        np.lib.format.write_array(member, np.asanyarray(value), allow_pickle=False)
        members.append((f"{key}.npy".encode(), member.getbuffer()))
    if _libdeflate is not None and all(len(data) < _ZIP32_LIMIT for _, data in members):
        return _zip_deflated(members)
    import zipfile

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1) as zf:
        for name, data in members:
            info = zipfile.ZipInfo(name.decode(), date_time=(1980, 1, 1, 0, 0, 0))
            info.external_attr = 0o644 << 16
            zf.writestr(info, data, compress_type=zipfile.ZIP_DEFLATED, compresslevel=1)
    return buf.getvalue()


_ZIP32_LIMIT = (1 << 32) - 1  # beyond: ZIP64 records, left to zipfile


def _zip_deflated(members) -> bytes:
    """A zip archive of ``(name, data)`` members, raw-deflated by libdeflate at level 1.

    PKWARE APPNOTE 6.3 layout: local headers, central directory, end record; every
    member dated 1980-01-01, mode 0644.
    """
    import struct

    date, time_ = (0 << 9) | (1 << 5) | 1, 0          # 1980-01-01 00:00:00 in DOS format
    parts, central, offset = [], [], 0
    for name, data in members:
        body = _libdeflate.deflate_compress(data, 1)
        crc = _libdeflate.crc32(data) & 0xFFFFFFFF
        local = struct.pack("<IHHHHHIIIHH", 0x04034B50, 20, 0, 8, time_, date, crc, len(body), len(data),
                            len(name), 0) + name
        central.append(struct.pack("<IHHHHHHIIIHHHHHII", 0x02014B50, 0x0314, 20, 0, 8, time_, date, crc,
                                   len(body), len(data), len(name), 0, 0, 0, 0, 0o644 << 16, offset) + name)
        parts += [local, body]
        offset += len(local) + len(body)
    if offset >= _ZIP32_LIMIT:
        raise ValueError("npz archive too large for a zip32 record")
    cd = b"".join(central)
    end = struct.pack("<IHHHHIIH", 0x06054B50, 0, 0, len(central), len(central), len(cd), offset, 0)
    return b"".join(parts) + cd + end


def _write_npz(path: Path, arrays: dict) -> None:
    """Write :func:`encode_npz` of ``arrays`` to ``path`` atomically."""
    data = encode_npz(arrays)
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


# ------------------------------------------------------------------ job size


@dataclass(frozen=True)
class JobEstimate:
    """What a render will take, estimated before it starts (:func:`estimate_job`).

    Parameters
    ----------
    frames : int
        Frames to render [-].
    output_bytes : int
        Expected size of the frame folder [B] (16-bit PNG of noisy frames ≈ 0.5 B/px,
        compressed per-pixel truth ≈ 3 B/px, per-row truth; measured on the paper rig).
    memory_bytes : int
        Expected peak memory of the renderer [B] (≈ 400 MB for Mitsuba and the
        scene, plus ≈ 120 B per pixel of one frame; measured: 350 MB at 0.15 Mpx,
        600 MB at 2.35 Mpx).
    """

    frames: int
    output_bytes: int
    memory_bytes: int

    def describe(self) -> str:
        """One line: frames, output size and memory.

        Returns
        -------
        str
            E.g. ``"720 frames, about 1.1 GB on disk, 0.7 GB of memory"``.
        """
        return (f"{self.frames:,} frames, about {_size(self.output_bytes)} on disk, "
                f"{_size(self.memory_bytes)} of memory")


def _size(n: float) -> str:
    for unit, scale in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{n / 1e6:.2g} MB"


def estimate_job(rig: Rig, frames: int, truth_pixels_every: int, workers: int = 1) -> JobEstimate:
    """Estimate a render's output size and memory from the sensor and the frame count.

    Parameters
    ----------
    rig : Rig
        The rig (binned already, if wanted): its sensor rows × columns.
    frames : int
        Frames to render [-].
    truth_pixels_every : int
        Per-pixel truth every N-th frame (0 = never) [-].
    workers : int, default 1
        Worker processes (:func:`sim.workers.render_with_workers`): each holds its own
        renderer; the main process then holds no renderer (≈ 150 MB).

    Notes
    -----
    A renderer holds ≈ 400 MB (Mitsuba, the scene) plus, per sensor pixel, ≈ 120 B for
    the ideal twin and ≈ 450 B for a realistic one
    (:func:`scheimpflug.model.rig.is_realistic`: speckle
    scratch arrays, transport images, subsurface tables) — measured peaks at full paper
    resolution (2.35 Mpx): 0.6 GB ideal, 1.45 GB realistic (a 360-frame pile scan).

    Returns
    -------
    JobEstimate
        Frames, expected folder size and peak memory [B].
    """
    px = rig.sensor.rows * rig.sensor.columns
    pixel_truth = 0 if truth_pixels_every <= 0 else -(-frames // truth_pixels_every)
    output = frames * (0.5 * px + 40 * rig.sensor.rows + 2000) + pixel_truth * 3.0 * px
    renderer = 400e6 + (450 if is_realistic(rig) else 120) * px
    memory = renderer if workers <= 1 else workers * renderer + 150e6
    return JobEstimate(frames=int(frames), output_bytes=int(output), memory_bytes=int(memory))


# ------------------------------------------------------------------ manifest


def generator_info() -> dict:
    """Program and library versions, for the manifest's ``generator`` key.

    Returns
    -------
    dict
        ``program``, ``python`` (version) and ``versions``: the installed
        version of scheimpflug, numpy, mitsuba, drjit, opencv-python-headless
        and trimesh (None when not installed).
    """
    import platform
    from importlib import metadata

    versions = {}
    for dist in ("scheimpflug", "numpy", "mitsuba", "drjit", "opencv-python-headless", "trimesh"):
        try:
            versions[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            versions[dist] = None
    return {"program": "scheimpflug render", "python": platform.python_version(),
            "versions": versions}


def build_manifest(rig: Rig, scenario: Scenario, seed: int, spp: int, variant: str,
                   generator: dict | None = None, render: dict | None = None) -> dict:
    """The manifest of a run (``"complete": false``).

    Parameters
    ----------
    rig : Rig
        The rig (written with ``rig_to_dict``).
    scenario : Scenario
        The scenario (name, parameters, frames).
    seed : int
        Run seed.
    spp : int
        Laser samples per lit sensor row (default render description).
    variant : str
        Mitsuba variant (default render description).
    generator : dict, optional
        Program and library versions (:func:`generator_info`).
    render : dict, optional
        Render description (e.g. :meth:`MitsubaTwin.describe`); replaces the
        default ``{"spp": spp, "variant": variant}``.

    Returns
    -------
    dict
        JSON-ready manifest with the keys of the module docstring, one entry
        per frame.
    """
    frames = [{"file": f"frames/{f.index:05d}{frame_suffix(rig.chain)}", "truth": f"truth/{f.index:05d}.npz",
               **f.stage_entry(), "exposure_ms": rig.sensor.exposure_ms if getattr(f, "exposure_ms", None) is None
               else float(f.exposure_ms), "seed": f.seed,
               "pixel_truth": scenario.wants_pixel_truth(f.index),
               **({"actual": f.actual} if getattr(f, "actual", None) else {}),
               **({"camera_seed": f.camera_seed} if getattr(f, "camera_seed", None) is not None else {})}
              for f in scenario.frames]
    return {
        "format": FORMAT,
        "complete": False,
        "rig": rig_to_dict(rig),
        "scenario": scenario.name,
        "scenario_params": dict(scenario.params, truth_pixels_every=scenario.truth_pixels_every),
        "seed": int(seed),
        "render": dict(render) if render else {"spp": int(spp), "variant": variant},
        "adc_bits": rig.sensor.adc_bits,
        "stripe_along": stripe_along(rig),
        "pixel_value": "raw ADC code in uint16, 0 … 2**adc_bits − 1 (not shifted to 16 bit)"
                       if not chain_is_on(rig.chain) else
                       f"the camera chain's 8-bit RGB {rig.chain.format} file ([chain], sim/chain.py)",
        "truth": {
            "per_frame": "truth/NNNNN.npz: stripe_u (rows,) f64 [px], stripe_point_mm (rows, 3) "
                         "f64 [mm], stripe_object_id (rows,) i16, stripe_count (rows,) u8; "
                         "secondary_u (rows, 4) f32 [px], secondary_share (rows, 4) f32, "
                         "secondary_fraction (rows,) f32, subsurface_fraction (rows,) f32 (from "
                         "the renderer's light split); frames with pixel_truth also point_mm "
                         "(rows, columns, 3) f32 [mm] and object_id (rows, columns) u16. "
                         "NaN / 0 = none. See sim/truth.py.",
            **({"pattern": TARGET_TRUTH} if scenario.name == "target" else {}),
            "reference_frame": ("stage frame with the part at angle 0" if scenario.name not in ("calibration", "target")
                                else "stage frame (the plate moves in it)") + (
                ", in the turntable's own frame (its up is the stage's -z: z the table's up, origin on its axis "
                "at the optical axis's height; sim.stages.ref_from_stage)"
                if rig.stage.axis_tilt_deg >= 90.0 else ""),
            "stripe_rule": "sheet mid-plane ∩ mesh, visible from the lens centre and lit by the "
                           "laser, crossing each row centre; primary = smallest u; stripe_count = "
                           "number of crossings",
            "mesh": "truth/mesh.ply" + (" (plate at the first stage position; truth/mesh_NNNNN.ply "
                                        "per frame)" if scenario.name == "calibration" else ""),
            "rig_truth": "truth/rig_truth.json",
        },
        "generator": dict(generator or {}),
        "frames": frames,
    }


def prepare_folder(out, manifest: dict) -> set[int]:
    """Create or reopen the frame folder.

    Removes stale temporary files and writes ``manifest`` (atomically).

    Parameters
    ----------
    out : str or pathlib.Path
        The frame folder (created with its ``frames/`` and ``truth/`` subfolders).
    manifest : dict
        The run's manifest (:func:`build_manifest`).

    Returns
    -------
    set of int
        Indices of the frames already complete (PNG and truth file present)
        when resuming the same run; empty for a new folder.

    Raises
    ------
    RenderError
        If ``out`` cannot be written, is a non-empty folder without a
        manifest, holds an unreadable manifest, or holds a different run
        (the message names the first differing key).
    """
    out = Path(out)
    create_folder(out, RenderError)
    done = _existing_run(out, manifest)
    for sub in ("frames", "truth"):
        (out / sub).mkdir(exist_ok=True)
    remove_temporaries(out, ("frames", "truth"))
    write_json_atomic(out / "manifest.json", manifest)
    return done


def _existing_run(out: Path, manifest: dict) -> set[int]:
    """Frames present of the same run in ``out`` (:func:`sim.jobfolder.check_identity`); else raise."""
    if check_identity(out, FRAME_FOLDER, {k: manifest.get(k) for k in _IDENTITY_KEYS}) is None:
        return set()
    # the frames stored in this folder (a dataset's Zarr sample lists chunks of its store instead)
    indices = [int(e["file"][7:-4]) for e in manifest["frames"]
               if e["file"].startswith("frames/") and e["file"].endswith((".png", ".jpg"))
               and e["file"][7:-4].isdigit()]
    suffix = _folder_suffix(manifest)
    return {i for i in indices if all(p.exists() for p in frame_paths(out, i, suffix))}


# ------------------------------------------------------------------ the loop


@dataclass
class RenderStats:
    """What a run did and where the time went.

    Parameters
    ----------
    frames_total : int, default 0
        Frames in the scenario.
    frames_rendered : int, default 0
        Frames rendered by this run.
    frames_skipped : int, default 0
        Frames already complete in the folder (resumed run).
    frames_without_stripe : list of int
        Indices of the rendered frames whose truth holds no stripe.
    seconds : dict of str to float
        Time per stage [s]: ``render``, ``noise``, ``png``, ``truth``,
        ``truth_pixels``, ``truth_write``.
    wall_s : float, default 0.0
        Wall time of the frame loop [s].
    """

    frames_total: int = 0
    frames_rendered: int = 0
    frames_skipped: int = 0
    frames_without_stripe: list = field(default_factory=list)
    seconds: dict = field(default_factory=lambda: {"render": 0.0, "noise": 0.0, "png": 0.0,
                                                   "truth": 0.0, "truth_pixels": 0.0,
                                                   "truth_write": 0.0})
    wall_s: float = 0.0


def _scene_truth_files(out: Path, rig: Rig, scenario: Scenario) -> None:
    write_json_atomic(out / "truth" / "rig_truth.json", rig_truth(rig))
    gain, dark = SensorModel.from_rig(rig).fixed_pattern((rig.sensor.rows, rig.sensor.columns))
    if (gain is not None or dark is not None) and not (out / "truth" / "sensor_maps.npz").exists():
        _write_npz(out / "truth" / "sensor_maps.npz",
                   {k: v for k, v in (("prnu_gain", gain), ("dark_e", dark)) if v is not None})
    if not (out / "truth" / "mesh.ply").exists():
        scenario.assembly.transformed(scenario.mesh_ref_from_part).to_ply(out / "truth" / "mesh.ply")
    if getattr(scenario, "background", ()) and not (out / "truth" / "background.ply").exists():
        from scenes import Assembly

        Assembly("background", scenario.background).to_ply(out / "truth" / "background.ply")   # stage frame
    if scenario.name == "calibration":
        for f in scenario.frames:
            p = out / "truth" / f"mesh_{f.index:05d}.ply"
            if not p.exists():
                scenario.assembly.transformed(f.ref_from_part).to_ply(p)


def _scene_truth(rig, mesh) -> SceneTruth:
    """The run's :class:`sim.truth.SceneTruth` (the faces in Morton blocks), made on first use."""
    if "scene_truth" not in mesh:
        mesh["scene_truth"] = SceneTruth(rig, mesh["vertices"], mesh["faces"], mesh["face_ids"])
    return mesh["scene_truth"]


def _frame_truth(rig, scenario, frame, caster, stats, mesh, light=None, defer=None, section=None) -> dict:
    """The frame's truth arrays (stripe, secondary light, per-pixel, the scenario's own).

    With a list ``defer`` (and no scenario truth of its own), the secondary-light truth
    — numpy on the light split, no scene query — is left out and ``defer`` receives
    ``(number of stripe arrays, the light split)`` for :func:`_complete_truth`.  A
    ``section`` future (:meth:`sim.truth.SceneTruth.section` of this frame, computed on
    another thread) saves computing the sheet's cut here.
    """
    t0 = time.perf_counter()
    truth = _scene_truth(rig, mesh)
    if section is None:
        stripe, _ = truth.frame(frame.rig_from_part, frame.ref_from_part, caster, frame.rig_from_laser)
    else:
        stripe, _ = truth.finish(section.result(), caster)
    arrays = stripe.arrays()
    split = light if light is not None and light.laser is not None else None
    if defer is not None and getattr(scenario, "frame_truth", None) is None:
        defer.extend((len(arrays), split))
    else:
        arrays.update(_secondary_arrays(rig, split))
    t1 = time.perf_counter()
    _add_seconds(stats, "truth", t1 - t0)
    if scenario.wants_pixel_truth(frame.index):
        ref_from_rig = frame.ref_from_part @ invert(frame.rig_from_part)
        if "directions" not in mesh:
            mesh["directions"] = pixel_directions(rig)     # per rig, once per run
        arrays["point_mm"], arrays["object_id"] = pixel_truth(rig, caster, ref_from_rig,
                                                              mesh["directions"])
        _add_seconds(stats, "truth_pixels", time.perf_counter() - t1)
    if getattr(scenario, "frame_truth", None) is not None:     # the scenario's own truth (sim.target)
        arrays = scenario.frame_truth(rig, scenario, frame, caster, arrays)
    return arrays


def _secondary_arrays(rig, split) -> dict:
    """The secondary-light truth of a frame's light split (None: the ideal twin's empty one), per stripe line."""
    if stripe_along(rig) == "rows":       # one line per column: the transposed frame (sim/truth.py)
        return secondary_truth(rig.sensor.columns, *(
            (split.laser.T, None if split.secondary is None else split.secondary.T,
             None if split.subsurface is None else split.subsurface.T) if split is not None else ()))
    return secondary_truth(rig.sensor.rows, *(
        (split.laser, split.secondary, split.subsurface) if split is not None else ()))


def _complete_truth(rig, arrays: dict, deferred: list, stats) -> dict:
    """Insert the deferred secondary-light truth after the stripe arrays (same key order)."""
    if not deferred:
        return arrays
    t0 = time.perf_counter()
    n, split = deferred
    items = list(arrays.items())
    out = dict(items[:n])
    out.update(_secondary_arrays(rig, split))
    out.update(items[n:])
    _add_seconds(stats, "truth", time.perf_counter() - t0)
    return out


def scene_arrays(scenario: Scenario) -> dict:
    """Per-run truth inputs, part frame.

    Vertices (n, 3) f64, faces (m, 3) i64, face_ids (m,) (plus, added on first use,
    ``scene_truth`` — the :class:`sim.truth.SceneTruth` of the run's rig — and
    ``directions``, the pixel chief rays).
    """
    m = scenario.assembly.combined_mesh()
    return {"vertices": np.asarray(m.vertices, dtype=np.float64),
            "faces": np.asarray(m.faces, dtype=np.int64),
            "face_ids": scenario.assembly.face_object_ids()}


def render_scenario(rig: Rig, scenario: Scenario, out, twin: Twin, manifest: dict,
                    progress: ProgressCallback | None = None,
                    warn: Callable[[str], None] | None = None, overlap: bool = True) -> RenderStats:
    """Render every frame of a scenario not yet complete in a frame folder.

    Per frame: render, sensor noise, geometric truth (these use the posed scene),
    secondary-light truth, truth file, PNG.  With ``overlap=True`` (the default) the
    frame loop is a pipeline: render up to the scene's queries, the scene's truth and
    the noise here; the sheet's cut through the mesh on a thread while the frame
    renders; the rest of a frame's image (surface speckle's deposit and coherent sums,
    ambient interpolation, splats) on a second thread while the next frame renders; the
    secondary-light truth and both writes of a finished frame in a background thread
    (libdeflate and zlib release the GIL), at most two frames behind; the files are the
    same byte for byte.  ``overlap=False`` runs every stage of a frame before the next
    frame (the loop before issue 27).  Frames whose truth holds no stripe are reported
    through ``warn`` (default: stderr); ``progress(done, total)`` is called after each
    frame written (:mod:`scheimpflug.callbacks`).  With ``overlap=True`` the ``finish``
    (the image finished on its thread), ``png`` and ``truth_write`` entries of
    ``RenderStats.seconds`` (and the section and secondary-light parts of ``truth``)
    are other threads' wall time and do not add up to the wall time.

    Parameters
    ----------
    rig : Rig
        The rig.
    scenario : Scenario
        The scenario to render.
    out : str or pathlib.Path
        The frame folder (created, or resumed when it holds the same run).
    twin : Twin
        The renderer and ray caster (:class:`MitsubaTwin`, or a test double).
    manifest : dict
        The run's manifest (:func:`build_manifest`); rewritten with
        ``"complete": true`` and ``frames_without_stripe`` at the end.
    progress : ProgressCallback, optional
        ``progress(done, total)`` after each frame written.
    warn : callable, optional
        Receives each warning as one line; default: print to stderr.
    overlap : bool, default True
        Finish each frame's surface speckle and write each frame (and its
        secondary-light truth) on other threads while the next frame is rendered.

    Returns
    -------
    RenderStats
        Frame counts and timings.

    Raises
    ------
    RenderError
        When another run is writing the folder (the message names it), the
        folder is unusable (:func:`prepare_folder`), a file cannot be written
        (a full disk: the folder stays resumable), or frames are missing at the end.
    """
    warn = warn or (lambda msg: print(f"warning: {msg}", file=sys.stderr))
    out = Path(out)

    def loop(todo, stats, bar, ledger):
        _frame_loop(rig, scenario, out, twin, todo, stats, warn, overlap, bar, ledger)

    return run_locked(out, warn, lambda: render_locked(rig, scenario, out, manifest, progress, warn, loop))


def run_locked(out: Path, warn, body):
    """``body()`` in the locked folder (:func:`sim.jobfolder.open_job`); an OSError becomes a RenderError."""
    with open_job(out, FRAME_FOLDER, None, warn):
        return body()


def render_locked(rig, scenario, out, manifest, progress, warn, loop) -> RenderStats:
    """The body of :func:`render_scenario`, run while holding the folder's lock.

    ``loop(todo, stats, bar, ledger)`` renders and writes the frames ``todo``.
    """
    done = prepare_folder(out, manifest)
    ledger = FileLedger(out)
    done = _verified(done, ledger, warn, _folder_suffix(manifest))
    _scene_truth_files(out, rig, scenario)
    stats = RenderStats(frames_total=len(scenario.frames), frames_skipped=len(done))
    t_start = time.perf_counter()
    todo = [f for f in scenario.frames if f.index not in done]
    bar = _Counter(progress, len(todo))
    loop(todo, stats, bar, ledger)
    stats.wall_s = time.perf_counter() - t_start
    ledger.write_sorted()
    _finish(out, manifest, scenario, stats, done)
    dark = {f.index for f in scenario.frames if getattr(f, "light", None) == "flood"}   # laser off by design
    unlit = [i for i in stats.frames_without_stripe if i not in dark]
    if unlit:
        warn(f"{len(unlit)} of {stats.frames_rendered} rendered frames hold no stripe: {index_ranges(unlit)}")
    return stats


def frame_file_names(index: int, suffix: str = ".png") -> list[str]:
    """A frame's files relative to its folder (PNG or the chain's file, truth), as the ledger records them."""
    return [p.as_posix() for p in frame_paths(Path(), index, suffix)]


def _verified(done: set[int], ledger: FileLedger, warn, suffix: str = ".png") -> set[int]:
    """The frames of ``done`` whose files match their ledger record; warns about the others."""
    bad = {i: reason for i in sorted(done) if (reason := ledger.mismatch(i, frame_file_names(i, suffix)))}
    if bad:
        first = min(bad)
        warn(f"rendering again {len(bad)} frame(s) whose files do not match {LEDGER_NAME}: "
             f"{index_ranges(bad)} (frame {first}: {bad[first]})")
    return done - set(bad)


class _Counter:
    """Counts finished frames and reports them through the progress callback."""

    def __init__(self, progress: ProgressCallback | None, total: int) -> None:
        self.progress, self.total, self.done = progress, total, 0
        report(progress, 0, total)

    def update(self) -> None:
        self.done += 1
        report(self.progress, self.done, self.total)


def _frame_loop(rig, scenario, out, twin, todo, stats, warn, overlap, bar, ledger=None) -> None:
    """The frames of ``todo``: pipelined on three threads (``overlap``) or one after the other.

    Pipelined: this thread does everything that uses the posed scene or Dr.Jit — it
    renders a frame up to its scene queries (:meth:`MitsubaTwin.begin`), tests its
    stripe truth's visibility on the posed scene and adds the sensor noise — Dr.Jit's
    pool at one thread, two for the noise's one kernel, unless the twin has a camera
    pass (:func:`sim.threads.drjit_threads`; two threads sharing it measured slower).
    The sheet's cut through the mesh (:meth:`sim.truth.SceneTruth.section`, numpy) runs
    on a thread while the frame renders.  What is left of a frame's image (the surface
    speckle's deposit and coherent sums, the ambient light's interpolation, the splats:
    numba and OpenCV, :meth:`sim.render.PendingLight.finish`) runs on a second thread
    while this one renders the next frame, which then gets its noise.  One background
    thread turns each finished frame into files — the secondary-light truth (numpy,
    numba), the truth archive and the PNG (libdeflate and zlib release the GIL) — at
    most two frames behind (:class:`_FileStage`).  The files are those of the
    sequential loop, byte for byte.
    """
    from concurrent.futures import ThreadPoolExecutor

    model = frame_model(rig)
    mesh = scene_arrays(scenario)
    if not overlap:
        for frame in todo:
            image, arrays = frame_products(rig, scenario, twin, frame, stats, warn, mesh, model)
            _finish_frame(out, model, frame, None, image, arrays, stats, ledger)
            bar.update()
        return
    if not todo:             # a complete folder resumed: nothing to set up
        return
    # one pool thread, unless a camera pass (a path tracer over every pixel) needs both cores
    camera = getattr(twin, "camera", None) is not None
    pool_threads, noise_threads = (None, None) if camera else (1, _noise_threads(rig))
    files = _FileStage(rig, out, model, stats, ledger, bar)
    scene_truth = _timed(stats, "truth", _scene_truth, rig, mesh)
    with drjit_threads(pool_threads), \
            ThreadPoolExecutor(max_workers=1, thread_name_prefix="frame-light") as finisher, \
            ThreadPoolExecutor(max_workers=1, thread_name_prefix="frame-section") as sections:
        waiting = None       # (frame, its finish on the other thread, its truth) of a frame not finished
        try:
            for frame in todo:
                section = sections.submit(_section, scene_truth, frame, stats)   # meanwhile: the render
                pending = _timed(stats, "render", _begin, twin, frame)
                if pending.done:             # nothing left to finish: noise now, then truth
                    with drjit_threads(noise_threads):
                        image = _noise(pending.light.image, model, frame, stats, _light_split(twin, frame))
                    truth = _truth_deferred(rig, scenario, twin, frame, stats, warn, mesh, section)
                    if waiting is not None:
                        _noise_and_files(waiting, model, stats, files, noise_threads)
                        waiting = None
                    files.submit(frame, image, truth)
                    continue
                truth = _truth_deferred(rig, scenario, twin, frame, stats, warn, mesh, section)
                finishing = finisher.submit(_timed, stats, "finish", pending.finish)
                if waiting is not None:     # the frame before: its speckle done meanwhile
                    _noise_and_files(waiting, model, stats, files, noise_threads)
                waiting = (frame, finishing, truth)
            if waiting is not None:
                _noise_and_files(waiting, model, stats, files, noise_threads)
        except BaseException:
            files.close(raise_failure=False)  # the frame being written finishes; this error is the one
            raise
        files.close()


#: frames of at least this many pixels get the noise's kernel on two pool threads (full
#: paper frames: 1.07× frames/s); smaller ones keep one — resizing the pool around every
#: frame cost more than it gave on 4 × 4 binned frames (benchmarks/RESULTS.md)
NOISE_POOL_MIN_PIXELS = 1_000_000


def _noise_threads(rig: Rig) -> int | None:
    """Dr.Jit pool threads for the noise's kernel in the pipelined loop (None: the loop's one)."""
    return 2 if rig.sensor.rows * rig.sensor.columns >= NOISE_POOL_MIN_PIXELS else None


def _begin(twin, frame):
    """The frame begun (:meth:`MitsubaTwin.begin`), or rendered whole by a twin without ``begin``."""
    if hasattr(twin, "begin"):
        return twin.begin(frame)
    from .render import FrameLight, PendingLight

    return PendingLight(FrameLight(twin.render(frame)))


def _truth_deferred(rig, scenario, twin, frame, stats, warn, mesh, section) -> tuple[dict, list]:
    """The frame's scene-bound truth now, its secondary-light truth deferred to the file stage."""
    deferred: list = []
    arrays = _frame_truth_checked(rig, scenario, twin, frame, stats, warn, mesh, deferred, section)
    return arrays, deferred


def _section(truth: SceneTruth, frame, stats):
    """The frame's sheet cut through the mesh (:meth:`sim.truth.SceneTruth.section`), timed as truth."""
    return _timed(stats, "truth", truth.section, frame.rig_from_part, frame.ref_from_part,
                  frame.rig_from_laser)


def _noise_and_files(waiting, model, stats, files, noise_threads) -> None:
    """A frame whose image was finished on another thread: its noise here, then its files."""
    frame, finishing, truth = waiting
    light = finishing.result()               # re-raises the finishing thread's failure
    with drjit_threads(noise_threads):
        image = _noise(light.image, model, frame, stats)
    files.submit(frame, image, truth)


class _FileStage:
    """The background thread that writes frames' files in order, at most ``depth`` frames behind.

    ``submit`` first waits until fewer than ``depth`` frames are pending (re-raising the
    failure of the oldest, before anything of the new frame is written) and counts the
    frames done on the progress bar.  Once a frame's files fail, the frames queued after
    it write nothing: the folder holds whole frames only, up to the one that failed.
    Two frames in flight let the render thread go on while the file thread catches up
    with a slow frame, instead of both waiting for each other in turn.
    """

    def __init__(self, rig, out, model, stats, ledger, bar, depth: int = 2) -> None:
        import threading
        from collections import deque
        from concurrent.futures import ThreadPoolExecutor

        self._args = (rig, out, model, stats, ledger)
        self._bar = bar
        self._depth = depth
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="frame-files")
        self._pending: deque = deque()
        self._failed = threading.Event()

    def _wait(self, keep: int = 0) -> None:
        while len(self._pending) > keep:
            self._pending.popleft().result()
            self._bar.update()

    def _write(self, *args) -> None:
        if self._failed.is_set():          # a frame before failed: write nothing of this one
            return
        try:
            _files_of_frame(*args)
        except BaseException:
            self._failed.set()
            raise

    def submit(self, frame, image, truth) -> None:
        self._wait(keep=self._depth - 1)
        rig, out, model, stats, ledger = self._args
        arrays, deferred = truth
        self._pending.append(self._pool.submit(self._write, rig, out, model, frame, image, arrays,
                                               deferred, stats, ledger))

    def close(self, raise_failure: bool = True) -> None:
        """Wait for the last frames' files (re-raising a failure unless told not to); stop the thread."""
        try:
            if raise_failure:
                self._wait()
        finally:
            self._pool.shutdown(wait=True)


def _files_of_frame(rig, out, model, frame, image, arrays, deferred, stats, ledger) -> None:
    """The background half of a pipelined frame: deferred truth, truth file, PNG."""
    _finish_frame(out, model, frame, None, image, _complete_truth(rig, arrays, deferred, stats),
                  stats, ledger)


def index_ranges(indices) -> str:
    """'0, 3–7, 9' for [0, 3, 4, 5, 6, 7, 9]."""
    parts, idx = [], sorted(indices)
    start = prev = idx[0]
    for i in idx[1:] + [None]:
        if i is not None and i == prev + 1:
            prev = i
            continue
        parts.append(f"{start}" if start == prev else f"{start}–{prev}")
        if i is not None:
            start = prev = i
    return ", ".join(parts)


_STATS_LOCK = threading.Lock()


def _add_seconds(stats: RenderStats, key: str, seconds: float) -> None:
    """stats.seconds[key] += seconds (both threads of the pipelined loop add to it)."""
    with _STATS_LOCK:
        stats.seconds[key] = stats.seconds.get(key, 0.0) + seconds


def _timed(stats: RenderStats, key: str, fn, *args):
    t0 = time.perf_counter()
    result = fn(*args)
    _add_seconds(stats, key, time.perf_counter() - t0)
    return result


def frame_products(rig, scenario, twin, frame, stats, warn, mesh, model) -> tuple:
    """One frame's raw ADC image and truth arrays: render, sensor noise, truth."""
    electrons = _timed(stats, "render", twin.render, frame)
    # the noise right after the render, before the truth's ray queries
    # (measured ≈ 40 ms/frame slower on 2 cores just after Dr.Jit's ray casts)
    image = _noise(electrons, model, frame, stats, _light_split(twin, frame))
    return image, _frame_truth_checked(rig, scenario, twin, frame, stats, warn, mesh)


def frame_model(rig: Rig):
    """What turns a frame's light into its file: the sensor (16-bit grey raw codes) or the camera chain.

    Parameters
    ----------
    rig : Rig
        The rig (``[sensor]``, ``[chain]``).

    Returns
    -------
    SensorModel or ChainModel
        :class:`sim.chain.ChainModel` when ``[chain] format`` is not ``"png16"``.
    """
    return ChainModel.from_rig(rig) if chain_is_on(rig.chain) else SensorModel.from_rig(rig)


def _light_split(twin, frame):
    """(laser, other light) of the frame when the twin keeps them apart (:meth:`MitsubaTwin.light_split`), else None."""
    split = getattr(twin, "light_split", None)
    return split(frame) if split is not None else None


def _noise(electrons, model, frame, stats, split=None) -> np.ndarray:
    """The frame's image: sensor noise seeded by the frame seed, and the camera chain when on.

    With the chain, ``split`` = (laser, other light) gives each its channel responses; without
    it (no camera pass) all the light takes the laser's (:mod:`sim.chain`).
    """
    exposure = getattr(frame, "exposure_factor", 1.0)
    if isinstance(model, ChainModel):
        laser, other = split if split is not None else (electrons, None)
        return _timed(stats, "noise", apply_chain, laser, other, model, frame_rng(frame.seed, 0), exposure)
    return _timed(stats, "noise", apply_sensor, electrons, model, frame_rng(frame.seed, 0), None, exposure)


def _frame_truth_checked(rig, scenario, twin, frame, stats, warn, mesh, defer=None, section=None) -> dict:
    """Truth arrays of one frame (main thread: uses the posed scene); warns if no stripe."""
    arrays = _frame_truth(rig, scenario, frame, twin.caster(frame), stats, mesh,
                          _twin_light(twin, frame), defer, section)
    stats.frames_rendered += 1
    if not np.isfinite(arrays["stripe_u"]).any():
        stats.frames_without_stripe.append(frame.index)
        if frame.index not in scenario.expected_empty:
            warn(f"frame {frame.index} ({describe_frame(frame)}) holds no stripe: nothing lit by the "
                 "laser is in view")
    return arrays


def _finish_frame(out, model, frame, electrons, image, arrays, stats, ledger=None) -> None:
    """Finish one frame: sensor noise (unless ``image`` is given), truth file, then PNG.

    The PNG's presence marks the frame complete; then the size and SHA-256 of
    both files go to the folder's ledger (what a resumed run verifies).
    """
    suffix = model.suffix if isinstance(model, ChainModel) else ".png"
    png, npz = frame_paths(out, frame.index, suffix)
    if image is None:
        image = _noise(electrons, model, frame, stats)
    _timed(stats, "truth_write", _write_npz, npz, arrays)
    _timed(stats, "png", write_frame_file, png, image, model)
    if ledger is not None:
        ledger.record(frame.index, frame_file_names(frame.index, suffix))


def describe_frame(frame: FrameSpec) -> str:
    """'stage 120 mm', 'angle 35°' or 'pose 3, laser': a frame's commanded position, for messages."""
    if frame.stage_mm is not None:
        return f"stage {frame.stage_mm:g} mm"
    if getattr(frame, "light", None) is not None:
        return f"pose {frame.pose_index}, {frame.light}"
    return f"angle {frame.angle_deg:g}°"


def _finish(out: Path, manifest: dict, scenario: Scenario, stats: RenderStats,
            skipped: set) -> None:
    suffix = _folder_suffix(manifest)
    missing = [e["file"] for e, f in zip(manifest["frames"], scenario.frames)
               if not all(p.exists() for p in frame_paths(out, f.index, suffix))]
    if missing:
        raise RenderError(f"{len(missing)} frames are missing after rendering (first: {missing[0]})")
    no_stripe = set(stats.frames_without_stripe)
    for i in skipped:   # frames complete before this run: read their truth
        with np.load(frame_paths(out, i)[1]) as z:
            if not np.isfinite(z["stripe_u"]).any():
                no_stripe.add(i)
    final = dict(manifest, complete=True, frames_without_stripe=sorted(no_stripe))
    write_json_atomic(out / "manifest.json", final)


def render_folder(rig: Rig, scenario_name: str, out, *, seed: int = 0, spp: int | None = None,
                  progress: ProgressCallback | None = None,
                  warn: Callable[[str], None] | None = None, workers: int = 1,
                  materials: MaterialSettings | None = None, **scenario_options) -> tuple[RenderStats, dict]:
    """Render a named scenario of ``rig`` into the frame folder ``out`` (the library's ``render``).

    Builds the scenario (:func:`sim.scenarios.build_scenario`), the Mitsuba twin
    and the manifest, then runs :func:`render_scenario` (resumable).  With
    ``workers`` ≥ 2 the frames are rendered by that many spawned worker processes
    (:func:`sim.workers.render_with_workers`): the same files, bit for bit.

    Parameters
    ----------
    rig : Rig
        The instrument (binned already, if wanted).
    scenario_name : {"calibration", "blocker", "rotary"}
        The scenario.
    out : path
        Frame folder to write (created; an interrupted run resumes).
    seed : int
        Run seed; same seed, same frames and truth, bit for bit.
    spp : int, optional
        Laser samples per lit sensor row (default: the renderer's).
    progress : ProgressCallback, optional
        ``progress(done, total)`` after each frame.
    warn : callable, optional
        Receives every warning (scenario, twin, frames without a stripe) as one
        line; default: stderr.
    workers : int, default 1
        Worker processes rendering frames at once (1 = this process; N ≥ 2: each
        worker's thread pools sized to cores // N).
    materials : MaterialSettings, optional
        The material tags' settings (default :class:`sim.materials.MaterialSettings`); given, the
        frames render in this process (a twin's identified albedo and roughness: ``render --twin``).
    **scenario_options
        Options of the scenario (``steps``, ``step_mm``, ``part``, ``step_deg`` …;
        :mod:`sim.scenarios`).

    Returns
    -------
    stats : RenderStats
        Frame counts and timings.
    manifest : dict
        The manifest as first written (``complete`` false; the file on disk
        is rewritten with ``complete`` true at the end).

    Raises
    ------
    RenderError
        No JIT variant of Mitsuba, an unwritable or foreign folder, a bad
        ``workers``, a frame that failed in a worker or a worker that died.
    ScheimpflugError
        An unknown scenario or option, a bad part.
    """
    warn = warn or (lambda msg: print(f"warning: {msg}", file=sys.stderr))
    if workers != 1 and chain_is_on(rig.chain):
        warn(f"the camera chain ([chain] format = {rig.chain.format!r}) renders in this process: "
             f"{workers} workers asked, 1 used")
        workers = 1
    if workers != 1 and materials is not None:
        warn(f"material settings other than the defaults render in this process: {workers} workers asked, 1 used")
        workers = 1
    if workers != 1:
        from .workers import RenderJob, render_with_workers  # it builds on this module

        job = RenderJob(rig, scenario_name, seed=seed, spp=spp, options=dict(scenario_options))
        return render_with_workers(job, out, workers, progress=progress, warn=warn)
    factory = None
    if materials is not None:
        def factory(rig_, assembly, **kw):
            return MitsubaTwin(rig_, assembly, materials=materials, **kw)
    scenario, twin, manifest, messages = build_run(rig, scenario_name, seed, spp, scenario_options, factory)
    for msg in messages:
        warn(msg)
    stats = render_scenario(rig, scenario, out, twin, manifest, progress=progress, warn=warn)
    return stats, manifest


def build_run(rig: Rig, scenario_name: str, seed: int, spp: int | None, options: dict,
              twin_factory: Callable | None = None) -> tuple[Scenario, Twin, dict, list[str]]:
    """A run's scenario, its twin and its manifest, and the warnings building them gave.

    Shared by :func:`render_folder` and the workers of :mod:`sim.workers` (each
    worker builds its own twin; the first one's manifest is the run's).
    ``twin_factory(rig, assembly, spp=…)`` makes the twin (default :class:`MitsubaTwin`).
    The warnings: the scenario's, then those of loading its parts (MeshWarning).
    """
    import warnings

    from .scenarios import build_scenario

    with warnings.catch_warnings(record=True) as caught:     # part loading warns (MeshWarning)
        warnings.simplefilter("always")
        scenario = build_scenario(scenario_name, rig, seed=seed, **options)
        twin = (twin_factory or MitsubaTwin)(rig, scenario.assembly, spp=spp,
                                             **({"background": scenario.background} if scenario.background else {}))
    describe = twin.describe() if hasattr(twin, "describe") else None
    manifest = build_manifest(rig, scenario, seed, getattr(twin, "spp", 1), getattr(twin, "variant", "unknown"),
                              generator_info(), describe)
    return scenario, twin, manifest, list(scenario.warnings) + [str(w.message) for w in caught]
