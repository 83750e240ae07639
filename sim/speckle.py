"""Surface-attached laser speckle: coherent imaging of the lit surface through the aperture.

Physics
-------
An optically rough surface lit by coherent light scatters with a phase that
varies randomly on the scale of the roughness.  The thin lens images that
field through its aperture: the field on the sensor is the surface field
convolved with the *coherent* point-spread function (the Fourier transform of
the pupil), and the intensity is its squared modulus — speckle (Goodman,
*Speckle Phenomena in Optics*, 2007, ch. 4–5).  Nothing about the statistics is
imposed here: the grain and the contrast follow from the model.

Model
-----
* *Scatterers attached to the part.*  A lattice of spacing δ in the part's own
  frame (the scene's part frame, so it moves with the part), each point
  jittered and given a circular complex Gaussian amplitude c_g by a hash of its
  lattice index and the part (:func:`_scatterer`).  The points within δ/2 of
  the surface, projected onto it, are the surface's scatterers; δ is chosen so
  that the image holds ≥ 1.5 of them per cell of the fine grid below.
* *Their phase.*  Each carries the optical path from the laser origin and to the
  lens centre, ψ_g = k·(|x_g − O_laser| + |x_g|): a rigid motion changes these
  paths non-uniformly across the surface, so a part that turns decorrelates its
  speckle even where the same surface stays lit, and a translated surface
  carries its speckle along (Goodman §5.x; the image-side quadratic phase is
  common to all scatterers at a sensor point and drops out of |U|²).
* *Imaging.*  Every scatterer lands at its chief-ray image on the sensor
  (:func:`scheimpflug.model.camera.project_points`, distortion included), is
  deposited bilinearly on a fine grid (s × s per pixel, spacing ≤ 0.7·λ·N_w) and
  the grid is convolved with the coherent PSF of the circular pupil, an Airy
  amplitude 2·J₁(x)/x, x = π·r/(λ·N_w), N_w = N·(1 + m) the working f-number at
  that image point (m the local magnification), stretched along the columns by
  1/cos ψ where the chief ray meets the tilted sensor at ψ from its normal.  The
  kernel is built in the frequency domain (pupil ÷ √ of the deposit's spectral
  shape, so that the field's spectrum is flat inside the pupil) and truncated
  at the second dark ring (90 % of the amplitude PSF's energy) with a cosine taper.
* *Intensity.*  S = |U|²/E|U|² on the fine grid (E from the kernel and the
  deposit's correlation; near silhouettes divided by the local coverage), its
  mean over each pixel's s × s samples is the pixel's speckle factor.  The laser
  image becomes I + I_c·(S − 1), with I_c the light weighted by its speckle
  contrast (per material, :data:`sim.materials.SPECKLE_CONTRAST`, times the
  laser's ``speckle_contrast`` for its coherence), so the expected image is
  unchanged and fully developed speckle of contrast 1 before pixel integration
  results where the contrast is 1.

Grain on the sensor: the Airy radius 1.22·λ·N·(1 + m) (first zero of the
field correlation; the intensity autocovariance |μ|² has its half maximum at
0.42 of it), longer by 1/cos ψ along the columns of a tilted sensor.

Only pixels with laser light (≥ ``min_electrons``) and their neighbours within
the kernel's reach are computed, tile by tile (16 × 16 px, in parallel; each
tile writes its own pixels, so the result does not depend on the thread count).

Approximations: the speckle of every pixel is that of the surface its chief ray
sees (defocused or inter-reflected light from elsewhere takes that pattern);
the laser's illumination phase is the fan's cylindrical wave from its origin;
the scatterers of a pixel's footprint lie on its tangent plane.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from scheimpflug.model.camera import SensorPose, lens_state
from scheimpflug.model.rig import Rig

from .lightsheet import light_sheet
from .truth import pixel_directions

__all__ = [
    "PreparedSpeckle",
    "SpeckleKernel",
    "SurfaceSpeckle",
    "coherent_kernel",
]

TILE_PX = 16
# The eight float64 of a fine cell, side by side so that a deposit touches one cache
# line per cell: the field (real, imaginary), Σw², the bilinear weights' cross sums
# with the neighbours (0, 1), (1, 0), (1, 1), (1, −1), and √Σw² / the occupancy.
_FIELD_RE, _FIELD_IM, _W2, _CROSS, _OCC = 0, 1, 2, 3, 7
_TAPER = 0.2           # cosine taper over the outer 20 % of the kernel radius
_RING = 2.2331         # second dark ring of the Airy amplitude, in units of λ·N_w


class SpeckleKernel:
    """Coherent PSF sampled on the fine grid, as a list of taps, with its lag sums.

    Parameters
    ----------
    lam_nw_fine : float
        λ·N_w in fine-grid samples [samples].
    stretch : float
        Elongation along the columns (1/cos ψ) [-].

    Attributes
    ----------
    taps : (2R + 1, 2R + 1) complex128
        The kernel.
    offsets : (n, 2) int64
        Row and column offsets of its non-zero taps.
    values : (n,) complex128
        Those taps.
    lags : (5,) float
        Σ|h|² and Re Σ h_k·h*_{k+e} for e = (0, 1), (1, 0), (1, 1), (1, −1).
    """

    def __init__(self, lam_nw_fine: float, stretch: float) -> None:
        self.taps = coherent_kernel(lam_nw_fine, stretch)
        r = self.taps.shape[0] // 2
        nz = np.argwhere(np.abs(self.taps) > 0)
        self.offsets = (nz - r).astype(np.int64)
        self.values = self.taps[nz[:, 0], nz[:, 1]].astype(np.complex128)
        h = self.taps
        self.lags = np.array([np.sum(np.abs(h) ** 2),
                              np.real(np.sum(h[:, :-1] * np.conj(h[:, 1:]))),
                              np.real(np.sum(h[:-1, :] * np.conj(h[1:, :]))),
                              np.real(np.sum(h[:-1, :-1] * np.conj(h[1:, 1:]))),
                              np.real(np.sum(h[:-1, 1:] * np.conj(h[1:, :-1])))])


def coherent_kernel(lam_nw_fine: float, stretch: float = 1.0) -> np.ndarray:
    """Airy amplitude PSF of a circular pupil on a grid, pre-emphasised for bilinear deposits.

    The pupil (cut-off 1/(2·λ·N_w), elliptical when stretched) is divided by
    √((1 + ½cos 2πf_u)(1 + ½cos 2πf_v)), the spectrum of a bilinear deposit of
    uncorrelated scatterers (neighbour correlation ¼ per axis), so that the field's
    spectrum is flat inside the pupil; transformed to space, truncated at the second
    dark ring of the Airy pattern with a cosine taper over its outer 20 %.

    Parameters
    ----------
    lam_nw_fine : float
        λ·N_w in grid samples [samples].
    stretch : float
        Elongation of the pattern along the grid's columns (axis 1) [-].

    Returns
    -------
    (2R + 1, 2R + 1) complex128
        Kernel taps, R = ⌈2.23·λ·N_w·stretch⌉.

    Raises
    ------
    ValueError
        If λ·N_w < 1 sample (the grid does not resolve the pupil).
    """
    if lam_nw_fine < 1.0:
        raise ValueError(f"λ·N_w = {lam_nw_fine:.3g} samples: the grid is too coarse for the pupil")
    radius = int(math.ceil(_RING * lam_nw_fine * stretch))
    n = 1 << int(math.ceil(math.log2(8 * radius + 8)))
    f = np.fft.fftfreq(n)
    fv, fu = np.meshgrid(f, f, indexing="ij")
    cutoff = 1.0 / (2.0 * lam_nw_fine)
    pupil = ((fu * stretch) ** 2 + fv**2 <= cutoff**2).astype(np.float64)
    shape = (1.0 + 0.5 * np.cos(2 * np.pi * fu)) * (1.0 + 0.5 * np.cos(2 * np.pi * fv))
    h = np.fft.fftshift(np.fft.ifft2(pupil / np.sqrt(shape)))
    c = n // 2
    taps = h[c - radius:c + radius + 1, c - radius:c + radius + 1]
    jj, ii = np.meshgrid(np.arange(-radius, radius + 1), np.arange(-radius, radius + 1))
    r = np.hypot(jj / stretch, ii) / (_RING * lam_nw_fine)
    taper = np.where(r <= 1 - _TAPER, 1.0,
                     np.where(r < 1, 0.5 * (1 + np.cos(np.pi * (r - 1 + _TAPER) / _TAPER)), 0.0))
    return (taps * taper).astype(np.complex128)


class SurfaceSpeckle:
    """The surface-attached speckle of a rig and a scene.

    Parameters
    ----------
    rig : Rig
        The instrument (wavelength, lens, laser origin).
    pose : SensorPose
        The sensor.
    scene : sim.scene.SimScene
        The parts (their part frames carry the scatterers).
    seed : int
        Seed of the surfaces' microstructure (not of the frame: the same part
        position gives the same speckle in every frame).
    min_electrons : float
        Pixels with less laser light get no speckle computed (their speckle is below
        their shot noise) [e⁻].
    min_row_fraction : float
        Nor do pixels below this fraction of their row's brightest: the stripe's far
        flanks and faint diffuse glow, which do not move a stripe detector [-].
    """

    def __init__(self, rig: Rig, pose: SensorPose, scene, seed: int = 0,
                 min_electrons: float = 1.0, min_row_fraction: float = 0.01) -> None:
        self.rig, self.pose, self.scene = rig, pose, scene
        self.seed = int(seed) & 0x7FFFFFFF
        self.min_electrons = float(min_electrons)
        self.min_row_fraction = float(min_row_fraction)
        self.wavelength_mm = rig.laser.wavelength_nm * 1e-6
        self.laser_origin_mm = np.asarray(light_sheet(rig).origin_mm, np.float64)
        m_min, m_max, stretch_max = self._ranges()
        lam_nw_min = self.wavelength_mm * rig.lens.f_number * (1 + m_min)
        self.fine = max(1, int(math.ceil(pose.pitch_mm / (0.75 * lam_nw_min))))
        fine_obj = pose.pitch_mm / self.fine / m_max    # a fine cell on the object [mm]
        self.lattice_mm = fine_obj / math.sqrt(1.2)      # ≥ 1.2 scatterers per fine cell
        lam_nw_max = self.wavelength_mm * rig.lens.f_number * (1 + m_max) * 1.05
        radius = math.ceil(_RING * lam_nw_max * self.fine / pose.pitch_mm * stretch_max * 1.02)
        self.margin_px = int(math.ceil((radius + 1) / self.fine))   # pixels whose scatterers matter
        self._kernels: dict = {}
        self._buffers: dict = {}
        self._directions = None       # chief rays of all pixels (rows, columns, 3), on first use
        self.last_fine: dict | None = None

    # ------------------------------------------------------------ geometry
    def _ranges(self) -> tuple[float, float, float]:
        """Magnification range and largest column stretch of the sensor's view.

        (min, max) lateral magnification m = f/(x − f) over the sheet the sensor sees, and
        the largest stretch 1/cos ψ of the chief rays on the sensor.
        """
        from scheimpflug.model.camera import sensor_point_from_pixel, sheet_point_from_pixel

        cols = np.linspace(0, self.pose.columns - 1, 9)
        rows = np.linspace(0, self.pose.rows - 1, 9)
        uv = np.stack(np.meshgrid(cols, rows), -1).reshape(-1, 2)
        x = sheet_point_from_pixel(self.rig, uv, self.pose)[:, 0]
        f = self.rig.lens.focal_length_mm
        m = f / (x[np.isfinite(x) & (x > f)] - f)
        q = sensor_point_from_pixel(self.pose, uv)
        stretch = float(np.max(np.linalg.norm(q, axis=1) / np.abs(q @ self.pose.normal)))
        if m.size == 0:
            return 0.1, 0.1, stretch
        return float(m.min()), float(m.max()), stretch

    def grain_px(self, magnification: float) -> float:
        """Airy radius 1.22·λ·N·(1 + m) of the speckle on the sensor [px].

        Parameters
        ----------
        magnification : float
            Lateral magnification m of the imaged point [-].

        Returns
        -------
        float
            The grain [px].
        """
        return 1.22 * self.wavelength_mm * self.rig.lens.f_number * (1 + magnification) \
            / self.pose.pitch_mm

    def _kernel(self, lam_nw_mm: float, stretch: float) -> SpeckleKernel:
        key = (round(math.log(lam_nw_mm) / 0.01), round(stretch / 0.01))
        if key not in self._kernels:
            lam_nw = math.exp(key[0] * 0.01) * self.fine / self.pose.pitch_mm
            self._kernels[key] = SpeckleKernel(lam_nw, key[1] * 0.01)
        return self._kernels[key]

    # ------------------------------------------------------------ public
    def apply(self, laser, coherent) -> np.ndarray:
        """Laser light with speckle.

        Parameters
        ----------
        laser : (rows, columns) float32
            Expected laser electrons without speckle [e⁻].
        coherent : (rows, columns) float32
            The same light weighted by its speckle contrast (≤ ``laser``) [e⁻].

        Returns
        -------
        (rows, columns) float32
            laser + coherent·(S − 1) [e⁻].
        """
        return self.prepare(laser).apply(laser, coherent)

    def prepare(self, laser) -> PreparedSpeckle:
        """The half of :meth:`pixel_speckle` that needs the posed scene: the lit pixels' chief-ray hits.

        What is left — the scatterers' deposit and the coherent sums, numba on arrays
        the result owns — is :meth:`PreparedSpeckle.pixel_speckle`, which may run on
        another thread while the scene is posed for the next frame (the pipelined frame
        loop, :func:`sim.writer.render_scenario`).  One prepared frame at a time may be
        finished (the deposit's scratch grids are the model's).

        Parameters
        ----------
        laser : (rows, columns) float
            Laser electrons (as :meth:`pixel_speckle`) [e⁻].

        Returns
        -------
        PreparedSpeckle
            The frame's lit pixels and their hits on the scene as posed now.
        """
        laser = np.asarray(laser)
        rows, cols = laser.shape
        lit = (laser >= self.min_electrons) \
            & (laser >= self.min_row_fraction * laser.max(axis=1, keepdims=True))
        if not lit.any():
            return PreparedSpeckle(self, (rows, cols), lit, None)
        need = _needed_pixels(lit, self.margin_px)
        return PreparedSpeckle(self, (rows, cols), lit, self._hit_rays(need))

    def pixel_speckle(self, laser, keep_fine: bool = False) -> np.ndarray:
        """Speckle factor S of each pixel (mean 1; 1 where no laser light).

        Parameters
        ----------
        laser : (rows, columns) float
            Laser electrons; where ≥ ``min_electrons`` and ≥ ``min_row_fraction`` of the
            row's maximum, S is computed [e⁻].
        keep_fine : bool
            Keep the fine-grid intensity |U|²/E|U|² of every computed tile in
            ``self.last_fine`` ({(tile row, tile column): (T·s, T·s) float64}).

        Returns
        -------
        (rows, columns) float32
            Mean-1 speckle factor [-].
        """
        return self.prepare(laser).pixel_speckle(keep_fine)

    def _speckle_of(self, shape, lit, hits, keep_fine: bool) -> np.ndarray:
        """:meth:`pixel_speckle` from the lit pixels and their hits (no scene query)."""
        out = np.ones(shape, np.float32)
        if hits is None:
            return out
        tiles = _lit_tiles(lit, TILE_PX)
        kernels, kidx = self._tile_kernels(tiles)
        index, part_pt, part_n, m12, part_idx, base_tiles = self._hit_arrays(hits, *shape)
        slot, cells, corr = self._deposit(index, part_pt, part_n, m12, part_idx, base_tiles)
        n_taps = max(len(k.values) for k in kernels)
        offsets = np.zeros((len(kernels), n_taps, 2), np.int64)
        values = np.zeros((len(kernels), n_taps), np.complex128)
        for i, k in enumerate(kernels):
            offsets[i, :len(k.values)] = k.offsets
            values[i, :len(k.values)] = k.values
        ntaps = np.array([len(k.values) for k in kernels], np.int64)
        lags = np.stack([k.lags for k in kernels])
        fine = np.zeros((len(tiles), TILE_PX * self.fine, TILE_PX * self.fine)) if keep_fine \
            else np.zeros((1, 1, 1))
        _pixel_means(tiles, TILE_PX, self.fine, self.margin_px, lit, slot, cells, corr,
                     offsets, np.ascontiguousarray(values.real), np.ascontiguousarray(values.imag),
                     ntaps, lags, kidx, out, keep_fine, fine)
        if keep_fine:
            self.last_fine = {(int(t[0]), int(t[1])): fine[i] for i, t in enumerate(tiles)}
        return out

    # ------------------------------------------------------------ internals
    def _deposit(self, index, part_pt, part_n, m12, part_idx, base_tiles):
        """Scatterers of the needed pixels, deposited on per-tile fine grids.

        Each tile's grid has a one-sample halo; halos are folded into their neighbours and
        the cells normalised to unit variance.

        Returns (slot (tile rows, tile columns) int64 — grid index of a tile or −1, cells
        (n, B, B, 8) float64 with B = T·s + 2 (index 0 = fine sample −1) holding per cell
        :data:`_FIELD_RE`, :data:`_FIELD_IM` (the normalised field), :data:`_OCC`
        (occupancy) and the deposit statistics, neighbour correlations (n, 4)).
        """
        t, s = TILE_PX, self.fine
        slot = -np.ones((-(-index.shape[0] // t), -(-index.shape[1] // t)), np.int64)
        slot[base_tiles[:, 0], base_tiles[:, 1]] = np.arange(len(base_tiles))
        b, n = t * s + 2, len(base_tiles)
        cells = self._scratch("cells", (n, b, b, 8), np.float64)   # zeroed per tile in parallel
        _deposit_base(base_tiles, t, s, index, part_pt, part_n, m12, part_idx, self.lattice_mm,
                      self.seed, self._camera_params(), self.laser_origin_mm,
                      2 * math.pi / self.wavelength_mm, cells, _CIS)
        _fold_halos(base_tiles, slot, t * s, cells)
        corr = np.zeros((n, 4))
        _normalise(cells, corr)
        return slot, cells, corr

    def _scratch(self, name: str, shape: tuple, dtype) -> np.ndarray:
        """An uninitialised array kept from frame to frame (no page faults for each frame)."""
        size = int(np.prod(shape))
        buf = self._buffers.get(name)
        if buf is None or buf.size < size:
            buf = self._buffers[name] = np.empty(size + size // 4, dtype)
        return buf[:size].reshape(shape)

    def _camera_params(self) -> np.ndarray:
        p, lens = self.pose, self.rig.lens
        state = lens_state(self.rig)          # the real lens's centre δ (0 when ideal)
        return np.concatenate([p.origin_mm, p.normal, p.u_dir, p.v_dir,
                               [p.pitch_mm, state.focal_length_mm, lens.k1, lens.k2,
                                state.centre_x_mm]]).astype(np.float64)

    def _tile_kernels(self, tiles: np.ndarray):
        """One kernel per tile from its centre: N_w = N·(1 + m) at the sheet point, stretch 1/cos ψ."""
        from scheimpflug.model.camera import sensor_point_from_pixel, sheet_point_from_pixel

        centre = tiles[:, ::-1].astype(np.float64) * TILE_PX + 0.5 * (TILE_PX - 1)
        x = sheet_point_from_pixel(self.rig, centre, self.pose)
        f = self.rig.lens.focal_length_mm
        m = np.where(np.isfinite(x[:, 0]) & (x[:, 0] > f), f / (x[:, 0] - f), 0.0)
        q = sensor_point_from_pixel(self.pose, centre)
        cos_psi = np.abs(q @ self.pose.normal) / np.linalg.norm(q, axis=1)
        lam_nw = self.wavelength_mm * self.rig.lens.f_number * (1 + m)
        kernels, index, keys = [], np.zeros(len(tiles), np.int64), {}
        for i, (ln, c) in enumerate(zip(lam_nw, cos_psi)):
            k = self._kernel(float(ln), float(1.0 / c))
            if id(k) not in keys:
                keys[id(k)] = len(kernels)
                kernels.append(k)
            index[i] = keys[id(k)]
        return kernels, index

    def _hit_rays(self, need: np.ndarray) -> tuple:
        """Chief-ray hits of the needed pixels on the scene as posed now (the scene query).

        Returns their rows and columns, the rays' directions (n, 3), the hits' distance,
        part index (−1 = none) and normal (:meth:`sim.scene.SimScene.first_hit_parts`), and
        the parts' rig_from_part (p, 4, 4) of this pose.
        """
        rr, cc = _nonzero(need)
        if self._directions is None:
            rows, cols = need.shape
            self._directions = pixel_directions(self.rig).reshape(rows, cols, 3)
        w = self._directions[rr, cc]
        t, idx, n = self.scene.first_hit_parts(w) if rr.size else (np.zeros(0),) * 3
        mats = np.stack([np.asarray(m, np.float64) for m in self.scene.rig_from_part])
        return rr, cc, w, t, idx, n, mats

    def _hit_arrays(self, rays: tuple, rows: int, cols: int):
        """The hits of :meth:`_hit_rays` in compact arrays (numpy, no scene query).

        Returns index (rows, columns) int32 into the arrays (−1 = no hit or not needed),
        part-frame point (n, 3) and normal (n, 3, toward the lens), rig_from_part rows
        (n, 12), part index (n,), and the (tile row, tile column) of the tiles holding
        hits, in row-major order.
        """
        rr, cc, w, t, idx, n, mats = rays
        index = np.full((rows, cols), -1, np.int32)
        sel = np.nonzero(idx >= 0)[0]
        m = mats[idx[sel]]
        p, n = t[sel, None] * w[sel], n[sel]
        n = np.where((np.sum(n * p, 1) > 0)[:, None], -n, n)
        rot, trans = m[:, :3, :3], m[:, :3, 3]
        index[rr[sel], cc[sel]] = np.arange(sel.size)
        n_tile_cols = -(-cols // TILE_PX)
        tiles = np.unique((rr[sel] // TILE_PX) * n_tile_cols + cc[sel] // TILE_PX)
        return (index, np.einsum("kji,kj->ki", rot, p - trans), np.einsum("kji,kj->ki", rot, n),
                np.ascontiguousarray(m[:, :3, :].reshape(-1, 12)), idx[sel].astype(np.int64),
                np.stack([tiles // n_tile_cols, tiles % n_tile_cols], 1).astype(np.int64))


class PreparedSpeckle:
    """One frame's speckle after its scene queries (:meth:`SurfaceSpeckle.prepare`).

    Parameters
    ----------
    model : SurfaceSpeckle
        The model that prepared it.
    shape : (int, int)
        The frame's (rows, columns).
    lit : (rows, columns) bool
        Pixels whose speckle is computed.
    hits : tuple or None
        Their neighbourhood's chief-ray hits (``SurfaceSpeckle._hit_rays``); None when
        nothing is lit.
    """

    def __init__(self, model: SurfaceSpeckle, shape: tuple[int, int], lit: np.ndarray, hits) -> None:
        self.model, self.shape, self.lit, self.hits = model, shape, lit, hits

    def pixel_speckle(self, keep_fine: bool = False) -> np.ndarray:
        """Speckle factor S of each pixel (:meth:`SurfaceSpeckle.pixel_speckle`).

        Parameters
        ----------
        keep_fine : bool
            As :meth:`SurfaceSpeckle.pixel_speckle`.

        Returns
        -------
        (rows, columns) float32
            Mean-1 speckle factor [-].
        """
        return self.model._speckle_of(self.shape, self.lit, self.hits, keep_fine)

    def apply(self, laser, coherent) -> np.ndarray:
        """Laser light with speckle, laser + coherent·(S − 1) (:meth:`SurfaceSpeckle.apply`).

        Parameters
        ----------
        laser : (rows, columns) float32
            The laser electrons this frame was prepared from [e⁻].
        coherent : (rows, columns) float32
            The same light weighted by its speckle contrast [e⁻].

        Returns
        -------
        (rows, columns) float32
            Laser light with speckle [e⁻].
        """
        s = self.pixel_speckle()
        if not (laser.dtype == coherent.dtype == np.float32):
            return (laser + coherent * (s - np.float32(1.0))).astype(np.float32)
        s -= np.float32(1.0)          # float32 in place: the same values, no frame-sized temporaries
        np.multiply(coherent, s, out=s)
        np.add(laser, s, out=s)
        return s


def _lit_tiles(lit: np.ndarray, t: int) -> np.ndarray:
    """(n, 2) int (tile row, tile column) of the tiles holding lit pixels, row-major."""
    rows, cols = lit.shape
    any_lit = np.logical_or.reduceat(lit, np.arange(0, rows, t), axis=0)
    any_lit = np.logical_or.reduceat(any_lit, np.arange(0, cols, t), axis=1)
    return np.argwhere(any_lit).astype(np.int64)


def _nonzero(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns (int64) of a 2-D bool mask's set pixels, row-major (as np.nonzero)."""
    import cv2

    pts = cv2.findNonZero(np.ascontiguousarray(mask).view(np.uint8))
    if pts is None:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    pts = pts.reshape(-1, 2).astype(np.int64)
    return pts[:, 1], pts[:, 0]


def _needed_pixels(lit: np.ndarray, margin: int) -> np.ndarray:
    """Pixels within ``margin`` of a lit one (their scatterers reach the lit pixels' field)."""
    import cv2

    k = np.ones((2 * margin + 1, 2 * margin + 1), np.uint8)
    return cv2.dilate(lit.astype(np.uint8), k) > 0


# ------------------------------------------------------------------ numba kernels
# error_model="numpy": no Python-style zero check before each floating-point division
# (none of these kernels divides by zero); the same results, the deposit 7–10 % faster.


@nb.njit(cache=True, error_model="numpy", nogil=True)
def _mix(h):  # pragma: no cover - compiled
    """splitmix64 finaliser."""
    h = (h ^ (h >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    h = (h ^ (h >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return h ^ (h >> np.uint64(31))


@nb.njit(cache=True, error_model="numpy", nogil=True)
def _cell_hash(i, j, k, key):  # pragma: no cover - compiled
    """64 random bits of lattice cell (i, j, k) of the part whose key is ``key``."""
    return _mix((np.uint64(i & 0x1FFFFF) | (np.uint64(j & 0x1FFFFF) << np.uint64(21))
                 | (np.uint64(k & 0x1FFFFF) << np.uint64(42))) ^ key)


_CIS_N = 4096
_CIS = np.exp(2j * np.pi * np.arange(_CIS_N + 1) / _CIS_N)


@nb.njit(cache=True, error_model="numpy", nogil=True)
def _cis(phase, table):  # pragma: no cover - compiled
    """exp(i·phase) by linear interpolation in a 4096-entry table (error < 3e-7).

    y − ⌊y⌋ is Python's y % 1.0 to the bit (both round 1 − frac once) without fmod.
    """
    y = phase / (2 * math.pi)
    x = (y - math.floor(y)) * (table.shape[0] - 1)
    i = int(x)
    f = x - i
    return table[i] * (1.0 - f) + table[i + 1] * f


@nb.njit(cache=True, error_model="numpy", nogil=True)
def _project(x, y, z, cam):  # pragma: no cover - compiled
    """Chief-ray image (u, v) [px] of a rig point (thin lens at x = cam[16], radial distortion, sensor plane)."""
    k1, k2, cx = cam[14], cam[15], cam[16]
    xr = x - cx
    t2 = (y * y + z * z) / (xr * xr)
    s = 1.0 + k1 * t2 + k2 * t2 * t2
    wx, wy, wz = -xr, -y * s, -z * s
    den = wx * cam[3] + wy * cam[4] + wz * cam[5]
    lam = ((cam[0] - cx) * cam[3] + cam[1] * cam[4] + cam[2] * cam[5]) / den
    qx, qy, qz = cx + lam * wx - cam[0], lam * wy - cam[1], lam * wz - cam[2]
    u = (qx * cam[6] + qy * cam[7] + qz * cam[8]) / cam[12]
    v = (qx * cam[9] + qy * cam[10] + qz * cam[11]) / cam[12]
    return u, v


@nb.njit(cache=True, error_model="numpy", nogil=True)
def _affine(m, p0, p1, p2):  # pragma: no cover - compiled
    """M (12,) = rows of a 3 × 4 rigid transform, applied to the point (p0, p1, p2)."""
    return (m[0] * p0 + m[1] * p1 + m[2] * p2 + m[3], m[4] * p0 + m[5] * p1 + m[6] * p2 + m[7],
            m[8] * p0 + m[9] * p1 + m[10] * p2 + m[11])


@nb.njit(cache=True, error_model="numpy", nogil=True)
def _tangents(n):  # pragma: no cover - compiled
    """Two unit tangents (t1, t2) of the normal n, as tuples (no allocation)."""
    if abs(n[0]) < 0.9:
        a0, a1, a2 = 1.0, 0.0, 0.0
    else:
        a0, a1, a2 = 0.0, 1.0, 0.0
    x, y, z = n[1] * a2 - n[2] * a1, n[2] * a0 - n[0] * a2, n[0] * a1 - n[1] * a0
    length = math.sqrt(x ** 2 + y ** 2 + z ** 2)
    x, y, z = x / length, y / length, z / length
    return (x, y, z), (n[1] * z - n[2] * y, n[2] * x - n[0] * z, n[0] * y - n[1] * x)


@nb.njit(cache=True, error_model="numpy", nogil=True)
def _jacobian(y, t1, t2, m12, cam):  # pragma: no cover - compiled
    """Pixel (u, v) of part point y and the 2 × 2 Jacobian d(u, v)/d(t1, t2) [px/mm]."""
    x0 = _affine(m12, y[0], y[1], y[2])
    u0, v0 = _project(x0[0], x0[1], x0[2], cam)
    eps = 0.01
    xa = _affine(m12, y[0] + eps * t1[0], y[1] + eps * t1[1], y[2] + eps * t1[2])
    xb = _affine(m12, y[0] + eps * t2[0], y[1] + eps * t2[1], y[2] + eps * t2[2])
    ua, va = _project(xa[0], xa[1], xa[2], cam)
    ub, vb = _project(xb[0], xb[1], xb[2], cam)
    return u0, v0, (ua - u0) / eps, (va - v0) / eps, (ub - u0) / eps, (vb - v0) / eps


@nb.njit(cache=True, error_model="numpy", nogil=True)
def _deposit_one(cells, fu, fv, are, aim):  # pragma: no cover - compiled
    """Bilinear deposit of one scatterer at fine coordinates (fu, fv); cross-weight statistics."""
    g = cells.shape[0]
    iu = int(math.floor(fu))
    iv = int(math.floor(fv))
    if iu < 0 or iv < 0 or iu + 1 >= g or iv + 1 >= g:
        return
    au, av = fu - iu, fv - iv
    w00, w01 = (1 - av) * (1 - au), (1 - av) * au
    w10, w11 = av * (1 - au), av * au
    c = cells[iv, iu]
    c[0] += w00 * are
    c[1] += w00 * aim
    c[2] += w00 * w00
    c[3] += w00 * w01          # (0, 1) neighbours
    c[4] += w00 * w10          # (1, 0)
    c[5] += w00 * w11          # (1, 1)
    c = cells[iv, iu + 1]
    c[0] += w01 * are
    c[1] += w01 * aim
    c[2] += w01 * w01
    c[4] += w01 * w11
    c[6] += w01 * w10          # (1, −1)
    c = cells[iv + 1, iu]
    c[0] += w10 * are
    c[1] += w10 * aim
    c[2] += w10 * w10
    c[3] += w10 * w11
    c = cells[iv + 1, iu + 1]
    c[0] += w11 * are
    c[1] += w11 * aim
    c[2] += w11 * w11


@nb.njit(cache=True, error_model="numpy", nogil=True)
def _deposit_pixel(r, c, part, y, n, m12, delta, seed, cam, lo, k_wave, cells,
                   gr0, gc0, s, off, table):  # pragma: no cover - compiled
    """Deposit the scatterers owned by pixel (r, c) (their chief-ray image in its square).

    The part's lattice is 2-D, in the plane of the two frame axes farthest from the
    normal: column (p1, p2) holds one scatterer, jittered in the column and lying on the
    surface along the third axis (so it stays on the surface when the part moves; the
    density is ≥ 1/δ² per area).  Its amplitude is circular with independent triangular
    real and imaginary parts (E|c|² = 1; sums of many are Gaussian), times
    exp(i·k·optical path), the path linear over the pixel's footprint.
    """
    t1, t2 = _tangents(n)
    u0, v0, j11, j21, j12, j22 = _jacobian(y, t1, t2, m12, cam)
    det = j11 * j22 - j12 * j21
    if abs(det) < 1e-12:
        return
    e1 = 0.5 * (abs(j22) + abs(j12)) / abs(det)      # pixel square → tangent half extents
    e2 = 0.5 * (abs(j21) + abs(j11)) / abs(det)
    axis = 0
    if abs(n[1]) > abs(n[axis]):
        axis = 1
    if abs(n[2]) > abs(n[axis]):
        axis = 2
    a1, a2 = (axis + 1) % 3, (axis + 2) % 3
    lo1 = int(math.floor((y[a1] - abs(t1[a1]) * e1 - abs(t2[a1]) * e2) / delta))
    hi1 = int(math.floor((y[a1] + abs(t1[a1]) * e1 + abs(t2[a1]) * e2) / delta))
    lo2 = int(math.floor((y[a2] - abs(t1[a2]) * e1 - abs(t2[a2]) * e2) / delta))
    hi2 = int(math.floor((y[a2] + abs(t1[a2]) * e1 + abs(t2[a2]) * e2) / delta))
    x0 = _affine(m12, y[0], y[1], y[2])
    du0, dv0 = u0 - c, v0 - r
    dl = math.sqrt((x0[0] - lo[0]) ** 2 + (x0[1] - lo[1]) ** 2 + (x0[2] - lo[2]) ** 2)
    dc = math.sqrt(x0[0] ** 2 + x0[1] ** 2 + x0[2] ** 2)
    phase0 = (k_wave * (dl + dc)) % (2 * math.pi)
    # ∇ of the path in the part frame: R^T·(unit(x0 − L) + unit(x0)), along t1 and t2
    e0 = (x0[0] - lo[0]) / dl + x0[0] / dc
    e1 = (x0[1] - lo[1]) / dl + x0[1] / dc
    e2 = (x0[2] - lo[2]) / dl + x0[2] / dc
    g1 = 0.0
    g2 = 0.0
    for a in range(3):
        grad = k_wave * (m12[a] * e0 + m12[4 + a] * e1 + m12[8 + a] * e2)
        g1 += grad * t1[a]
        g2 += grad * t2[a]
    scale = 1.0 / 4294967296.0
    key = _mix((np.uint64(part + 1) * np.uint64(0x9E3779B97F4A7C15)) ^ np.uint64(seed)
               ^ (np.uint64(axis + 1) << np.uint64(61)))
    m16 = np.uint64(0xFFFF)
    m32 = np.uint64(0xFFFFFFFF)
    u16 = 1.0 / 65536.0
    root3 = math.sqrt(3.0)
    for p1 in range(lo1, hi1 + 1):
        for p2 in range(lo2, hi2 + 1):
            # the scatterer of lattice column (p1, p2): jittered in the a1–a2 plane, on the
            # surface along the part's `axis` (the axis nearest the normal)
            hj = _cell_hash(p1, p2, 0, key)
            da1 = (p1 + ((hj & m32) + 0.5) * scale) * delta - y[a1]
            da2 = (p2 + ((hj >> np.uint64(32)) + 0.5) * scale) * delta - y[a2]
            dax = -(n[a1] * da1 + n[a2] * da2) / n[axis]
            if axis == 0:
                d0, d1, d2 = dax, da1, da2
            elif axis == 1:
                d0, d1, d2 = da2, dax, da1
            else:
                d0, d1, d2 = da1, da2, dax
            s1 = t1[0] * d0 + t1[1] * d1 + t1[2] * d2      # tangent coordinates
            s2 = t2[0] * d0 + t2[1] * d1 + t2[2] * d2
            du = du0 + j11 * s1 + j12 * s2
            dv = dv0 + j21 * s1 + j22 * s2
            if not (-0.5 <= du < 0.5 and -0.5 <= dv < 0.5):
                continue
            # optical path laser → scatterer → lens centre, linear in the tangent offset
            # (curvature term ≈ |δ|²/(2L) < 1e-5 mm over a pixel footprint)
            ha = _mix(hj ^ np.uint64(0xD1B54A32D192ED03))  # amplitude bits
            cre = (((ha & m16) + ((ha >> np.uint64(16)) & m16)) * u16 - 1.0) * root3
            cim = ((((ha >> np.uint64(32)) & m16) + (ha >> np.uint64(48))) * u16 - 1.0) * root3
            a = (cre + 1j * cim) * _cis(phase0 + g1 * s1 + g2 * s2, table)
            fu = (c + du - gc0 + 0.5) * s - 0.5 + off
            fv = (r + dv - gr0 + 0.5) * s - 0.5 + off
            _deposit_one(cells, fu, fv, a.real, a.imag)


@nb.njit(cache=True, error_model="numpy", nogil=True, parallel=True)
def _deposit_base(base_tiles, t, s, index, part_pt, part_n, m12, part_idx, lattice, seed, cam,
                  lo, k_wave, cells, table):  # pragma: no cover - compiled
    """Each needed pixel's scatterers, once, on the fine grid of its own tile (offset 1).

    The tile's cells are zeroed first (they arrive uninitialised).
    """
    rows, cols = index.shape
    for i in nb.prange(base_tiles.shape[0]):
        cells[i] = 0.0
        tr, tc = base_tiles[i, 0], base_tiles[i, 1]
        for r in range(tr * t, min(rows, tr * t + t)):
            for c in range(tc * t, min(cols, tc * t + t)):
                j = index[r, c]
                if j >= 0:
                    _deposit_pixel(r, c, part_idx[j], part_pt[j], part_n[j], m12[j], lattice,
                                   seed, cam, lo, k_wave, cells[i], tr * t, tc * t, s, 1.0,
                                   table)


@nb.njit(cache=True, error_model="numpy", nogil=True)
def _fold_halos(base_tiles, slot, n, cells):  # pragma: no cover - compiled
    """Add each tile's halo cells (fine index −1 and n) into the neighbour tile they belong to."""
    for i in range(base_tiles.shape[0]):
        tr, tc = base_tiles[i, 0], base_tiles[i, 1]
        for a in range(n + 2):
            for b in range(n + 2):
                if 1 <= a <= n and 1 <= b <= n:
                    continue
                if cells[i, a, b, _W2] == 0.0:
                    continue
                dr = -1 if a == 0 else (1 if a == n + 1 else 0)
                dc = -1 if b == 0 else (1 if b == n + 1 else 0)
                nr, nc = tr + dr, tc + dc
                if nr < 0 or nc < 0 or nr >= slot.shape[0] or nc >= slot.shape[1] \
                        or slot[nr, nc] < 0:
                    continue
                k = slot[nr, nc]
                a2, b2 = a - dr * n, b - dc * n
                for e in range(_OCC):
                    cells[k, a2, b2, e] += cells[i, a, b, e]


@nb.njit(cache=True, error_model="numpy", nogil=True, parallel=True)
def _normalise(cells, corr):  # pragma: no cover - compiled
    """O = Σ w·c / √Σw² on occupied interior cells; mean neighbour correlation per tile.

    √Σw² of every cell once (in the occupancy's place, which it then becomes); the
    correlation sums run over the cells in row-major order.
    """
    n = cells.shape[1] - 2
    for i in nb.prange(cells.shape[0]):
        cell = cells[i]
        for a in range(n + 2):
            for b in range(n + 2):
                w2 = cell[a, b, _W2]
                cell[a, b, _OCC] = math.sqrt(w2) if w2 > 0.0 else 0.0
        sums = np.zeros(4)
        counts = np.zeros(4)
        for a in range(1, n + 1):
            for b in range(1, n + 1):
                norm = cell[a, b, _OCC]
                if norm == 0.0:
                    continue
                for e in range(4):      # neighbours (0, 1), (1, 0), (1, 1), (1, −1)
                    a2 = a + (0 if e == 0 else 1)
                    b2 = b + (1 if e == 0 else (0 if e == 1 else (1 if e == 2 else -1)))
                    if 1 <= a2 <= n and 1 <= b2 <= n and cell[a2, b2, _OCC] != 0.0:
                        sums[e] += cell[a, b, _CROSS + e] / (norm * cell[a2, b2, _OCC])
                        counts[e] += 1.0
        for a in range(n + 2):
            for b in range(n + 2):
                norm = cell[a, b, _OCC]
                if 1 <= a <= n and 1 <= b <= n and norm != 0.0:
                    cell[a, b, _FIELD_RE] /= norm
                    cell[a, b, _FIELD_IM] /= norm
                    cell[a, b, _OCC] = 1.0
                else:
                    cell[a, b, _OCC] = 0.0
        for e in range(4):
            corr[i, e] = sums[e] / counts[e] if counts[e] > 0 else 0.0


@nb.njit(cache=True, error_model="numpy", nogil=True)
def _window(slot, cells, n, fa0, fb0, size, wr, wi, wocc):  # pragma: no cover - compiled
    """Copy a size × size window of the normalised field and occupancy out of the tile grids.

    The window starts at global fine row fa0 and column fb0; the field goes to the real
    and imaginary planes wr, wi (zero outside the computed tiles), block by block of
    the tiles it overlaps.  Returns whether every cell is occupied.
    """
    wr[:, :] = 0.0
    wi[:, :] = 0.0
    wocc[:, :] = 0.0
    full = True
    for tr in range(fa0 // n, (fa0 + size - 1) // n + 1):
        a_lo, a_hi = max(fa0, tr * n), min(fa0 + size, tr * n + n)
        for tc in range(fb0 // n, (fb0 + size - 1) // n + 1):
            b_lo, b_hi = max(fb0, tc * n), min(fb0 + size, tc * n + n)
            if tr < 0 or tc < 0 or tr >= slot.shape[0] or tc >= slot.shape[1] \
                    or slot[tr, tc] < 0:
                full = False
                continue
            k = slot[tr, tc]
            for fa in range(a_lo, a_hi):
                row = cells[k, fa - tr * n + 1]
                for fb in range(b_lo, b_hi):
                    c = row[fb - tc * n + 1]
                    wr[fa - fa0, fb - fb0] = c[_FIELD_RE]
                    wi[fa - fa0, fb - fb0] = c[_FIELD_IM]
                    o = c[_OCC]
                    wocc[fa - fa0, fb - fb0] = o
                    if o == 0.0:
                        full = False
    return full


@nb.njit(cache=True, error_model="numpy", nogil=True)
def _row_span(lit, r, c0, c1):  # pragma: no cover - compiled
    """First and one-past-last lit column of row r within [c0, c1) (c1, c1 when none)."""
    lo, hi = c1, c1
    for c in range(c0, c1):
        if lit[r, c]:
            if lo == c1:
                lo = c
            hi = c + 1
    return lo, hi


@nb.njit(cache=True, error_model="numpy", nogil=True)
def _convolve_row(wr, wi, wocc, a0, b0, b1, cb, hr, hi, offsets, ntap, full, ur, ui, cv):
    # pragma: no cover - compiled
    """Field h ⊛ o (and coverage Σ|h|²·occ) at window row a0, columns b0…b1 − 1 (+ cb).

    Taps outer, columns inner (vectorised): every sample sums its taps in tap order.
    """
    m = b1 - b0
    u_r, u_i, c_v = ur[b0:b1], ui[b0:b1], cv[b0:b1]
    u_r[:] = 0.0
    u_i[:] = 0.0
    c_v[:] = 0.0
    for q in range(ntap):
        hre, him = hr[q], hi[q]
        ra = a0 - offsets[q, 0]
        sh = cb - offsets[q, 1] + b0
        orow, irow = wr[ra, sh:sh + m], wi[ra, sh:sh + m]
        for j in range(m):
            u_r[j] += hre * orow[j] - him * irow[j]
            u_i[j] += hre * irow[j] + him * orow[j]
        if not full:
            crow = wocc[ra, sh:sh + m]
            h2 = hre * hre + him * him
            for j in range(m):
                c_v[j] += h2 * crow[j]


@nb.njit(cache=True, error_model="numpy", nogil=True, parallel=True)
def _pixel_means(tiles, t, s, margin, lit, slot, cells, corr, offsets, values_re, values_im,
                 ntaps, lags, kidx, out, keep_fine, fine):  # pragma: no cover - compiled
    """S of each lit pixel: mean over its s × s fine samples of |h ⊛ o|²/(E|U|²·coverage).

    Each fine row of a tile is convolved over the span of its lit pixels at once, the
    taps of every sample summed in the kernel's tap order.
    """
    rows, cols = lit.shape
    n = t * s
    size = (t + 2 * margin) * s
    for i in nb.prange(tiles.shape[0]):
        tr, tc = tiles[i, 0], tiles[i, 1]
        k = kidx[i]
        own = slot[tr, tc]
        lg = lags[k]
        power = lg[0]
        if own >= 0:
            for e in range(4):
                power += 2.0 * corr[own, e] * lg[e + 1]
        fa0, fb0 = (tr * t - margin) * s, (tc * t - margin) * s
        wr = np.empty((size, size))
        wi = np.empty((size, size))
        wocc = np.empty((size, size))
        full = _window(slot, cells, n, fa0, fb0, size, wr, wi, wocc)
        ntap = ntaps[k]
        ur = np.empty(n)
        ui = np.empty(n)
        cv = np.empty(n)
        acc = np.empty(t)
        cov = np.empty(t)
        c_end = min(cols, tc * t + t)
        for r in range(tr * t, min(rows, tr * t + t)):
            lo, hi = _row_span(lit, r, tc * t, c_end)
            if lo == hi:
                continue
            j0, j1 = lo - tc * t, hi - tc * t
            for j in range(j0, j1):
                acc[j] = 0.0
                cov[j] = 0.0
            for fi in range(s):
                a0 = (r - tr * t + margin) * s + fi
                _convolve_row(wr, wi, wocc, a0, j0 * s, j1 * s, margin * s, values_re[k],
                              values_im[k], offsets[k], ntap, full, ur, ui, cv)
                for j in range(j0, j1):
                    if not lit[r, tc * t + j]:
                        continue
                    for fj in range(s):
                        b = j * s + fj
                        c1 = 1.0 if full else cv[b] / lg[0]
                        val = ur[b] * ur[b] + ui[b] * ui[b]
                        acc[j] += val / power
                        cov[j] += c1
                        if keep_fine:
                            fine[i, fi + (r - tr * t) * s, b] = val / (power * max(c1, 1e-9))
            for j in range(j0, j1):
                if lit[r, tc * t + j]:
                    cj = cov[j] / (s * s)
                    out[r, tc * t + j] = acc[j] / (s * s) / cj if cj > 0.25 else 1.0
