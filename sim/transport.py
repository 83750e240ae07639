"""Multi-bounce light transport of the laser pass: paths beyond the first surface.

The renderer (:mod:`sim.render`) traces the laser's rays to their first hit and
splats each hit through the thin lens.  This module continues those paths
(rig key ``[twin] bounces`` = N > 1) and adds the light that goes *into*
translucent materials (``[twin] subsurface``):

Per path vertex at depth k = 1 … N (k = 1: the first hit):

1. *Camera connection* (k ≥ 2; k = 1 is the renderer's): a new aperture sample
   A, the BSDF evaluated toward A (Mitsuba ``BSDF.eval`` in importance mode:
   f·cos θ), a shadow ray, and the splat
   ``Φ = β · f cos θ · Ω_ap`` at the image of the vertex (β the power the path
   carries).
2. *Translucent surface* (subsurface on): the boundary's BSDF is sampled; light
   it transmits random-walks inside (:func:`sim.subsurface.random_walk`), its
   next-event splats go to a fixed-point image, and light leaving the material
   continues outside as the path's next segment.
3. *Continuation* (k < N): ``BSDF.sample`` (importance mode) gives the next
   direction and the throughput weight f·cos θ/pdf; from depth ``rr_depth`` on,
   Russian roulette keeps a path with probability q = min(β/β₀, 0.95) and
   divides its power by q (unbiased).  Paths are compacted between depths.

This is Mitsuba's own particle tracer (``ptracer``) restricted to the laser:
the tests compare the two on a scene both can render.  Randomness is
stateless per (frame key, path, depth, dimension) (Mitsuba's TEA hash) or a
PCG32 stream per path inside a walk, so results do not depend on thread count
or on compaction.  Shading normals are the geometric ones (meshes carry no
vertex normals), so no adjoint shading-normal correction is needed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba
import numpy as np

from .lens import LensConnection
from .scene import numpy_rows
from .subsurface import FIXED_POINT_SCALE, WalkMedium, hg_eval, random_walk

__all__ = [
    "LightTransport",
    "SplatBatch",
    "TransportResult",
]


@dataclass
class SplatBatch:
    """Splats of one path depth (numpy).

    Parameters
    ----------
    depth : int
        Path depth k of the vertices (1 = first surface).
    uv : (2, n) float32
        Pixel coordinates [px].
    value : (n,) float32
        Flux [W].
    contrast : (n,) float32
        Speckle contrast of the light of each splat [-].
    """

    depth: int
    uv: np.ndarray
    value: np.ndarray
    contrast: np.ndarray


@dataclass
class TransportResult:
    """Light beyond the first surface's direct reflection.

    Parameters
    ----------
    batches : list of SplatBatch
        Surface splats of depths ≥ 2.
    subsurface : dict
        {1 or 2: (rows, columns) expected electrons} of light that walked inside a
        translucent material entered at depth 1 (the first surface's own subsurface
        light) or ≥ 2 (secondary) [e⁻].
    walks : tuple
        (number of subsurface walks, total events of those walks).
    """

    batches: list = field(default_factory=list)
    subsurface: dict = field(default_factory=dict)
    walks: tuple = (0, 0)


class LightTransport:
    """Continues light-tracing paths from their first hits (Dr.Jit, wavefront per depth).

    Parameters
    ----------
    mi, dr : modules
        ``mitsuba`` (JIT variant set) and ``drjit``.
    scene : sim.scene.SimScene
        The posed scene (its ``media`` decide which parts are translucent).
    lens : LensConnection
        Camera connection.
    channel : int
        RGB channel of the laser wavelength.
    bounces : int
        Path depth N (≥ 1).
    shape : (int, int)
        Sensor (rows, columns).
    electrons_per_watt : float
        Conversion of splat flux to electrons [e⁻/W].
    rr_depth : int
        First depth at which Russian roulette may end a path.
    max_walk_steps : int
        Event limit of a subsurface walk.
    contrast : (n_parts + 1,) float
        Speckle contrast of each part's surface light (index = part index + 1; 0 = none).
    thinning : int
        Only one path in ``thinning`` (chosen at random within each consecutive block of
        that many, its power × ``thinning``) continues beyond the first surface: the
        secondary light is dimmer and broader than the stripe and needs fewer samples
        (unbiased; more variance in the secondary light only).
    walk_thinning : int
        Likewise, one path in ``walk_thinning`` that enters a translucent material without
        a table (g ≠ 0) walks in it (each walk splats at ~10–100 vertices, so the
        subsurface light needs fewer walks than the surface light needs paths).
    """

    def __init__(self, mi, dr, scene, lens: LensConnection, channel: int, bounces: int,
                 shape: tuple[int, int], electrons_per_watt: float, rr_depth: int = 3,
                 max_walk_steps: int = 512, contrast=None, thinning: int = 1,
                 walk_thinning: int = 1) -> None:
        self._mi, self._dr = mi, dr
        self.scene, self.lens, self.channel = scene, lens, channel
        self.bounces, self.rr_depth, self.max_walk_steps = bounces, rr_depth, max_walk_steps
        self.shape = shape
        self.thinning = int(thinning)
        self.walk_thinning = int(walk_thinning)
        self.electrons_per_watt = electrons_per_watt
        #: trace depths 2 … N in one symbolic loop (:meth:`_fused_depths`); False: the
        #: wavefront loop of one set of kernels per depth (kept for comparison and for media
        #: without a table, which random-walk)
        self.fused = True
        media = scene.media
        self.has_media = any(m is not None for m in media)
        cols = [[0.0] * (len(media) + 1) for _ in range(5)]
        for i, m in enumerate(media):
            if m is not None:
                for c, v in enumerate((1.0, m.sigma_s_per_mm, m.sigma_a_per_mm, m.g, m.eta)):
                    cols[c][i + 1] = v
        self._media = [mi.Float(c) for c in cols]   # is_medium, σ_s, σ_a, g, η by part + 1
        n = len(media) + 1
        self._contrast = mi.Float(list(contrast) if contrast is not None else [1.0] * n)

    @property
    def active(self) -> bool:
        """Whether anything beyond the renderer's first-surface splats is to be traced."""
        return self.bounces > 1 or self.has_media

    # ------------------------------------------------------------ random numbers
    def _rand(self, s, path_id, depth, dim: int):
        """Uniform [0, 1) for (frame key s, path, depth, dimension): stateless TEA hash.

        ``depth`` is a Python int or, inside the fused loop, a ``mi.UInt32`` (the same
        salt modulo 2³²).
        """
        mi = self._mi
        if isinstance(depth, int):
            salt = mi.UInt32((0x632BE5AB * (depth + 1) + 0x85157AF5 * (dim + 1)) & 0xFFFFFFFF)
        else:
            salt = mi.UInt32(0x632BE5AB) * (depth + 1) \
                + mi.UInt32((0x85157AF5 * (dim + 1)) & 0xFFFFFFFF)
        return mi.sample_tea_float32(path_id, s ^ salt, 6)

    # ------------------------------------------------------------ main loop
    def trace(self, si, ray_d, beta, s, frame) -> TransportResult:
        """Continue paths from their first hits.

        Parameters
        ----------
        si : mitsuba.SurfaceInteraction3f
            First hits, scene frame.
        ray_d : mitsuba.Vector3f
            Direction of the rays that made them (scene frame).
        beta : mitsuba.Float
            Power of each path [W] (0 for dead lanes).
        s : mitsuba.UInt32
            Opaque frame key.
        frame : tuple
            ``(scene_from_rig, rig_from_scene)`` opaque transforms.

        Returns
        -------
        TransportResult
            Splats of depths ≥ 2 and the subsurface images.
        """
        mi, dr = self._mi, self._dr
        result = TransportResult()
        path_id = dr.arange(mi.UInt32, dr.width(beta))
        beta0 = mi.Float(beta)
        active = si.is_valid() & (beta > 0)
        if self.fused and self.bounces > 1 and self._fusable():
            wo, weight, entered = self._scatter(si, ray_d, beta, path_id, 1, s, frame, active,
                                                result)
            ray, beta, beta0, path_id, active = self._next(si, wo, weight, entered, beta, beta0,
                                                           path_id, 1, s, active)
            if dr.width(beta) > 0:
                self._fused_depths(ray, beta, beta0, path_id, active, s, frame, result)
            return result
        for depth in range(1, self.bounces + 1):
            if depth > 1:
                result.batches.append(self._connect(si, beta, path_id, depth, s, frame))
            if depth == self.bounces and not self.has_media:
                break
            wo, weight, entered = self._scatter(si, ray_d, beta, path_id, depth, s, frame,
                                                active, result)
            if depth == self.bounces:
                break
            ray, beta, beta0, path_id, active = self._next(si, wo, weight, entered, beta, beta0,
                                                           path_id, depth, s, active)
            if dr.width(beta) == 0:
                break
            si = self.scene.scene.ray_intersect(ray, active)
            ray_d = ray.d
            active &= si.is_valid()
            dr.eval(si, active)
        return result

    def _fusable(self) -> bool:
        """Whether the fused loop can trace this scene: no medium, or every medium tabulated."""
        return not self.has_media or all(t is not None for t in self._tables_for_media())

    def _fused_depths(self, ray, beta, beta0, path_id, active, s, frame, result) -> None:
        """Depths 2 … N of every path in one symbolic Dr.Jit loop (one kernel, no readback).

        The loop body is the wavefront code's depth (camera connection, BSDF sampling, the
        tabulated media's entry geometry and exits, Russian roulette) on lanes that stay in
        place instead of being compacted; what the wavefront code read back per depth is
        scattered into slot (depth − 2)·n + lane of flat buffers and read once afterwards,
        in lane (= path) order, so the splats and the subsurface light are the wavefront
        code's, in its order.  ``dr.while_loop`` records the body once
        (``JitFlag.SymbolicLoops``), as Mitsuba's own integrators do.
        """
        mi, dr = self._mi, self._dr
        n, last = dr.width(beta), self.bounces
        slots = n * (last - 1)
        media = self.has_media
        if media:
            self._exit_table_arrays()
        lane = dr.arange(mi.UInt32, n)
        width = dr.opaque(mi.UInt32, n)      # not a literal: the kernel is the same every frame
        splat = [dr.zeros(mi.Float, slots) for _ in range(4)]        # u, v, value, contrast
        geo = [dr.zeros(mi.Float, slots) for _ in range(15)] if media else []  # 14 + ok
        walks = dr.zeros(mi.UInt32, slots) if media else None

        def cond(depth, o, d, b, act):
            return act

        def body(depth, o, d, b, act):
            ray_k = mi.Ray3f(o, d)
            si = self.scene.scene.ray_intersect(ray_k, act)
            act = act & si.is_valid()
            slot = (depth - 2) * width + lane
            value, uv, contrast = self._connect_values(si, b, path_id, depth, s, frame)
            for buf, x in zip(splat, (uv.x, uv.y, value, contrast)):
                dr.scatter(buf, x, slot, act)
            sample = act & ((depth < last) | media)
            wo, weight, entered, part = self._sample_bsdf(si, ray_k.d, path_id, depth, s, sample)
            out = None
            if media:
                is_med = (dr.gather(mi.Float, self._media[0], part) > 0.5) & sample
                cols, ok = self._entry_columns(si, ray_k.d, b, part, path_id, depth, s, frame,
                                               is_med)
                for buf, x in zip(geo, [*cols, mi.Float(1.0)]):
                    dr.scatter(buf, mi.Float(x), slot, ok)
                goes_on = entered & (depth < last)
                dr.scatter(walks, mi.UInt32(1), slot, goes_on)
                out = self._table_exits(si, ray_k.d, b * weight, part, path_id, depth, s,
                                        goes_on)
            o, d, b, alive = self._continue(si, wo, weight, entered, out, b, beta0, path_id,
                                            depth, s, act)
            return depth + 1, o, d, b, alive & (depth < last)

        state = (mi.UInt32(2) + 0 * lane, mi.Point3f(ray.o), mi.Vector3f(ray.d), mi.Float(beta),
                 mi.Bool(active))
        dr.while_loop(state=state, cond=cond, body=body, labels=("depth", "o", "d", "beta", "active"),
                      label="sim.transport: depths 2 … N")
        dr.eval(*splat, *geo, walks)
        self._read_fused(n, splat, geo, walks, result)

    def _read_fused(self, n, splat, geo, walks, result) -> None:
        """The fused loop's buffers → splat batches and subsurface light, depth by depth."""
        u, v, value, contrast = (np.asarray(b, np.float32).reshape(-1, n) for b in splat)
        if geo:
            cols = np.stack([np.asarray(b, np.float32) for b in geo]).reshape(15, -1, n)
            n_walks = int(np.asarray(walks, np.uint32).sum())
            result.walks = (result.walks[0] + n_walks, result.walks[1])
        for k in range(u.shape[0]):
            keep = value[k] != 0.0
            result.batches.append(SplatBatch(k + 2, np.stack([u[k, keep], v[k, keep]]),
                                             value[k, keep], contrast[k, keep]))
            if geo:
                sel = cols[14, k] != 0.0
                if sel.any():
                    img = result.subsurface.get(2)
                    if img is None:
                        img = result.subsurface[2] = np.zeros(self.shape, np.float32)
                    _convolve_groups(img, cols[:14, k][:, sel].astype(np.float64), self._tables,
                                     self.electrons_per_watt, coarse=True)

    def _connect_values(self, si, beta, path_id, depth, s, frame):
        """Camera connection of path vertices: (flux [W], pixel, speckle contrast), Dr.Jit."""
        mi, dr = self._mi, self._dr
        to_scene, to_rig = frame
        active = si.is_valid() & (beta > 0)
        u_ap = mi.Point2f(self._rand(s, path_id, depth, 0), self._rand(s, path_id, depth, 1))
        p = to_rig @ si.p
        geo, uv, ok, a = self.lens.connect(p, active, u_ap)
        wo = to_scene @ mi.Vector3f(dr.normalize(a - p))
        ctx = mi.BSDFContext(mi.TransportMode.Importance)
        f_cos = si.bsdf().eval(ctx, si, si.to_local(wo), ok)[self.channel]
        ok &= ~self.scene.scene.ray_test(si.spawn_ray_to(to_scene @ a), ok)
        value = dr.select(ok, beta * f_cos * geo, 0.0)
        contrast = dr.gather(mi.Float, self._contrast, self.scene.part_index_dr(si))
        return value, uv, contrast

    def _connect(self, si, beta, path_id, depth, s, frame) -> SplatBatch:
        """Camera connection of the vertices of one depth (≥ 2) → a splat batch."""
        dr = self._dr
        value, uv, contrast = self._connect_values(si, beta, path_id, depth, s, frame)
        dr.eval(value, uv, contrast)
        return SplatBatch(depth, numpy_rows(uv, np.float32), np.asarray(value, np.float32),
                          np.asarray(contrast, np.float32))

    def _scatter(self, si, ray_d, beta, path_id, depth, s, frame, active, result):
        """Sample each vertex's BSDF; the subsurface light of the light entering a medium.

        Tabulated media (:class:`sim.subsurface.SubsurfaceTable`): the camera-bound light
        from the table's response, the light going on from the table's exits; other
        media: random walks that splat at every vertex.  Returns (outgoing direction
        (scene), throughput weight, entered-medium mask); lanes that left a medium get
        the exit ray through ``self._exits``.
        """
        mi, dr = self._mi, self._dr
        wo, weight, entered, part = self._sample_bsdf(si, ray_d, path_id, depth, s, active)
        is_med = (dr.gather(mi.Float, self._media[0], part) > 0.5) & active
        self._exits = None
        if not self.has_media or not bool(dr.any(is_med)[0]):
            return wo, weight, entered
        tabulated = self._tabulated_light(si, ray_d, beta, part, path_id, depth, s, frame,
                                          is_med, result)
        continues = depth < self.bounces
        if tabulated and continues:
            self._exits = self._table_exits(si, ray_d, beta * weight, part, path_id, depth, s,
                                            entered)
            result.walks = (result.walks[0] + int(dr.count(entered)[0]), result.walks[1])
        elif not tabulated:
            walks, power = entered, beta * weight
            if self.walk_thinning > 1:      # one walk per block of paths, its power × m
                m = self.walk_thinning
                pick = mi.sample_tea_32(path_id // m, s ^ mi.UInt32(0x68E31DA4 + depth), 6)[0] % m
                walks = entered & ((path_id % m) == pick)
                power = power * float(m)
            self._exits = self._walk(si, wo, power, part, path_id, depth, s, frame, walks, result,
                                     with_nee=not tabulated)
        return wo, weight, entered

    def _sample_bsdf(self, si, ray_d, path_id, depth, s, active):
        """BSDF samples of path vertices (importance mode), translucent hits' frames turned first.

        Returns (outgoing direction (scene), throughput weight f·cos θ/pdf of the laser's
        channel, entered-medium mask, part index + 1); ``si`` is updated in place.
        """
        mi, dr = self._mi, self._dr
        part = self.scene.part_index_dr(si)
        is_med = (dr.gather(mi.Float, self._media[0], part) > 0.5) & active
        self._outside_frame(si, ray_d, is_med)
        ctx = mi.BSDFContext(mi.TransportMode.Importance)
        u1 = self._rand(s, path_id, depth, 2)
        u2 = mi.Point2f(self._rand(s, path_id, depth, 3), self._rand(s, path_id, depth, 4))
        bs, w = si.bsdf().sample(ctx, si, u1, u2, active)
        wo = si.to_world(bs.wo)
        weight = w[self.channel]
        entered = is_med & (mi.Frame3f.cos_theta(bs.wo) < 0.0) & (weight > 0)
        return wo, weight, entered, part

    def _outside_frame(self, si, ray_d, mask):
        """Turn the shading frame of translucent hits toward the side the light came from."""
        mi, dr = self._mi, self._dr
        flip = mask & (dr.dot(si.n, ray_d) > 0.0)
        n = dr.select(flip, -si.n, si.n)
        si.n = n
        si.sh_frame = mi.Frame3f(dr.select(flip, -si.sh_frame.n, si.sh_frame.n))
        si.wi = si.to_local(-ray_d)
        return si

    # ------------------------------------------------------------ subsurface
    def _walk(self, si, d_in, power, part, path_id, depth, s, frame, entered, result,
              with_nee: bool = True):
        """Random walks of the light that entered media.

        Returns the exit rays (scene frame); for media without a table the walks also
        splat their next-event light.
        """
        mi, dr = self._mi, self._dr
        med = WalkMedium(*[dr.gather(mi.Float, col, part) for col in self._media[1:]])
        local = mi.Frame3f(-si.n)               # z of the walk's local frame points inward
        rng = mi.PCG32(size=dr.width(power), initstate=mi.UInt64(s) * 0x9E3779B97F4A7C15
                       + (depth + 1), initseq=mi.UInt64(path_id))
        nee, target = None, None
        if with_nee:
            u_ap = mi.Point2f(self._rand(s, path_id, depth, 5), self._rand(s, path_id, depth, 6))
            conn = self._nee_frame(si, local, med, self.lens.aperture_point(u_ap), frame, entered)
            target = self._subsurface_image(result, 1 if depth == 1 else 2)

            def nee(x, d, w, act, u, lane):
                self._nee_splat(x, d, w, act, med, conn, u, lane, target)

        walk = random_walk(mi, dr, med, local.to_local(d_in), power, rng, entered,
                           self.max_walk_steps, nee)
        exit_p = mi.Point3f(si.p + local.to_world(mi.Vector3f(walk.position)) + 1e-4 * si.n)
        exit_d = local.to_world(walk.direction)
        dr.eval(walk.exited, exit_p, exit_d, walk.weight, *([target] if with_nee else []))
        n_walks = int(dr.count(entered)[0])
        steps = int(dr.sum(dr.select(entered, walk.steps, 0))[0])
        result.walks = (result.walks[0] + n_walks, result.walks[1] + steps)
        return walk.exited & entered, exit_p, exit_d, walk.weight

    # ------------------------------------------------------------ tabulated subsurface light
    def _tabulated_light(self, si, ray_d, beta, part, path_id, depth, s, frame, is_med,
                         result) -> bool:
        """Camera-bound subsurface light of translucent hits from the media's tables.

        Each hit's incident power, entry image, angles and local projection are read out;
        hits are grouped by 16-pixel tile and medium, and each group's entry image is
        convolved with the medium's tabulated response (:class:`sim.subsurface.SubsurfaceTable`)
        mapped onto the sensor.  Returns False if a medium cannot be tabulated (g ≠ 0), in
        which case the walks splat instead.
        """
        if any(t is None for t in self._tables_for_media()):
            return False
        geo = self._entry_geometry(si, ray_d, beta, part, path_id, depth, s, frame, is_med)
        if geo is None:
            return True
        key = 1 if depth == 1 else 2
        img = result.subsurface.get(key)
        if img is None:
            img = result.subsurface[key] = np.zeros(self.shape, np.float32)
        _convolve_groups(img, geo, self._tables, self.electrons_per_watt, coarse=depth > 1)
        return True

    def _table_exits(self, si, ray_d, power, part, path_id, depth, s, entered):
        """Exits of the light entering tabulated media, drawn from the tables' walks.

        Each lane takes one of the exit samples of its medium's table
        (:attr:`sim.subsurface.SubsurfaceTable.exit_samples`) at its angle of incidence
        (one of the two neighbouring tabulated angles, chosen with the linear
        interpolation's weights), placed in the frame of its entry point (x forward along
        the incidence plane, z into the material), with the power entering times the
        table's exit albedo.  Returns (exited, point, direction, power) like the walks.
        """
        from .subsurface import TABLE_INCIDENCE_DEG, SubsurfaceTable

        mi, dr = self._mi, self._dr
        slot, albedo, cols = self._exit_table_arrays()
        n_angles, n_samples = len(TABLE_INCIDENCE_DEG), SubsurfaceTable.EXIT_SAMPLES
        step = TABLE_INCIDENCE_DEG[1] - TABLE_INCIDENCE_DEG[0]     # uniform, from 0°
        n = si.n
        d = dr.normalize(ray_d)
        cos_in = dr.clip(-dr.dot(d, n), 0.0, 1.0)
        x = dr.minimum(dr.acos(cos_in) * (180.0 / math.pi) / step, n_angles - 1.0)
        k = mi.UInt32(dr.floor(x))
        k = dr.select(self._rand(s, path_id, depth, 8) < x - mi.Float(k),
                      dr.minimum(k + 1, n_angles - 1), k)
        tab = dr.gather(mi.Int32, slot, part)
        ok = entered & (tab >= 0)
        row = mi.UInt32(dr.maximum(tab, 0)) * n_angles + k
        j = dr.minimum(mi.UInt32(self._rand(s, path_id, depth, 9) * n_samples), n_samples - 1)
        ex, ey, dx, dy, dz = [dr.gather(mi.Float, c, row * n_samples + j, ok) for c in cols]
        weight = power * dr.gather(mi.Float, albedo, row, ok)
        tangent = d + cos_in * n                       # d − (d·n)·n
        forward = dr.select(dr.squared_norm(tangent) > 1e-12, dr.normalize(tangent),
                            mi.Frame3f(n).s)
        inward = -n
        across = dr.cross(inward, forward)
        point = mi.Point3f(si.p + ex * forward + ey * across + 1e-4 * n)
        direction = dr.normalize(dx * forward + dy * across + dz * inward)
        return ok & (weight > 0), point, direction, weight

    def _exit_table_arrays(self):
        """The tables' exit samples as Dr.Jit arrays: (table slot by part + 1, albedo, 5 columns)."""
        mi = self._mi
        if getattr(self, "_exit_arrays", None) is None:
            self._tables_for_media()
            slots, unique = [-1], []
            for table in self._tables[1:]:
                if table is None:
                    slots.append(-1)
                    continue
                if not any(table is t for t in unique):
                    unique.append(table)
                slots.append(next(i for i, t in enumerate(unique) if t is table))
            albedo = np.concatenate([t.exit_albedo for t in unique])
            cols = np.concatenate([t.exit_samples.reshape(-1, 5) for t in unique]).T
            self._exit_arrays = (mi.Int32(slots), mi.Float(albedo),
                                 [mi.Float(np.ascontiguousarray(c)) for c in cols])
        return self._exit_arrays

    def _tables_for_media(self) -> list:
        """The :class:`SubsurfaceTable` of each part's medium (None entries: not tabulable)."""
        if getattr(self, "_tables", None) is None:
            cache: dict = {}
            tables = [None]
            for m in self.scene.media:
                if m is None:
                    tables.append(None)
                    continue
                if m not in cache:
                    cache[m] = _table_for(m)
                tables.append(cache[m])
            self._tables = tables
        return [t for t, m in zip(self._tables[1:], self.scene.media) if m is not None]

    def _entry_geometry(self, si, ray_d, beta, part, path_id, depth, s, frame, is_med):
        """Per translucent hit: part + 1, power × aperture solid angle, image, Jacobian, angles.

        Directions on the surface are measured in a basis (b1, b2) that depends on the
        normal only (b1 ⊥ the part frame's z, or x for horizontal faces), so that hits of
        one tile share it: the Jacobian is ∂(u, v)/∂(b1, b2); the incidence plane's forward
        direction and the view direction are given as azimuths in it (weighted by their
        sines, so that normal incidence or view carry no direction).
        """
        dr = self._dr
        cols, ok = self._entry_columns(si, ray_d, beta, part, path_id, depth, s, frame, is_med)
        dr.eval(*cols, ok)      # one kernel: a gather from an unevaluated column evaluates it alone
        idx = dr.compress(ok)
        if dr.width(idx) == 0:
            return None
        cols = [dr.gather(type(c), c, idx) for c in cols]
        dr.eval(*cols)
        out = np.stack([np.asarray(c, np.float64) for c in cols])
        return out

    def _entry_columns(self, si, ray_d, beta, part, path_id, depth, s, frame, is_med):
        """The 14 columns of :meth:`_entry_geometry` for every lane, and the lanes that count."""
        mi, dr = self._mi, self._dr
        to_scene, to_rig = frame
        n = si.n
        d = dr.normalize(ray_d)
        cos_in = dr.clip(-dr.dot(d, n), 0.0, 1.0)
        up = dr.select(dr.abs(n.z) < 0.9, mi.Vector3f(0.0, 0.0, 1.0), mi.Vector3f(1.0, 0.0, 0.0))
        t_inc = dr.normalize(dr.cross(up, n))          # b1
        t_perp = dr.cross(n, t_inc)                      # b2
        u_ap = mi.Point2f(self._rand(s, path_id, depth, 5), self._rand(s, path_id, depth, 6))
        a_rig = self.lens.aperture_point(u_ap)
        a_scene = to_scene @ a_rig
        visible = is_med & (beta > 0) & ~self.scene.scene.ray_test(si.spawn_ray_to(a_scene), is_med)
        w = dr.normalize(a_scene - si.p)
        cos_o = dr.dot(w, n)
        geo, uv0, ok, _ = self.lens.connect_at(to_rig @ si.p, visible & (cos_o > 1e-3), a_rig)
        eps = 0.05  # [mm]
        uv1 = self.lens.landing(to_rig @ mi.Point3f(si.p + eps * t_inc), a_rig)
        uv2 = self.lens.landing(to_rig @ mi.Point3f(si.p + eps * t_perp), a_rig)
        ok &= (dr.abs(uv1.x - uv0.x) + dr.abs(uv1.y - uv0.y) + dr.abs(uv2.x - uv0.x)
               + dr.abs(uv2.y - uv0.y)) < 100.0 * eps          # a real lens: < 100 px/mm
        cols = [part, beta * geo, uv0.x, uv0.y, (uv1.x - uv0.x) / eps, (uv1.y - uv0.y) / eps,
                (uv2.x - uv0.x) / eps, (uv2.y - uv0.y) / eps, dr.acos(cos_in),
                dr.acos(dr.minimum(cos_o, 1.0)),    # float32 rounding: ω·n can exceed 1 head-on
                dr.dot(d, t_inc), dr.dot(d, t_perp), dr.dot(w, t_inc), dr.dot(w, t_perp)]
        return cols, ok

    def _nee_frame(self, si, local, med, a_rig, frame, entered) -> dict:
        """Per-walk constants of the camera connection through the boundary.

        The lens point A is ~10⁵ penetration depths away, so the outside direction ω_o,
        the refracted inside direction ω_i, the Fresnel transmittance and the aperture's
        solid angle are those of the entry point for the whole walk, and the image of an
        exit point e = entry + δ (δ in the tangent plane, ≲ mm) is uv₀ + J·δ, J the
        projection's Jacobian (finite differences, second-order error ≈ |δ|²·M/(L·p):
        0.03 px at 1 mm).  One shadow ray per walk decides whether the entry point sees A.
        """
        mi, dr = self._mi, self._dr
        to_scene, to_rig = frame
        a_scene = to_scene @ a_rig
        visible = entered & ~self.scene.scene.ray_test(si.spawn_ray_to(a_scene), entered)
        w_o = local.to_local(dr.normalize(a_scene - si.p))
        cos_o = -w_o.z
        cos_i = dr.safe_sqrt(1.0 - (1.0 - cos_o * cos_o) / (med.eta * med.eta))
        f, _, _, _ = mi.fresnel(-cos_i, med.eta)
        trans = dr.select(med.eta == 1.0, 1.0, 1.0 - f)
        p0 = to_rig @ si.p
        geo, uv0, ok, _ = self.lens.connect_at(p0, visible & (cos_o > 1e-4), a_rig)
        eps = 0.05  # [mm]
        uv1 = self.lens.landing(to_rig @ mi.Point3f(si.p + eps * local.s), a_rig)
        uv2 = self.lens.landing(to_rig @ mi.Point3f(si.p + eps * local.t), a_rig)
        k = dr.select(ok, trans * cos_o / (med.eta * med.eta * cos_i) * geo, 0.0) \
            * (self.electrons_per_watt * FIXED_POINT_SCALE)
        return {"uv0": uv0, "ju": (uv1 - uv0) / eps, "jv": (uv2 - uv0) / eps, "k": k,
                "w_i": mi.Vector3f(w_o.x / med.eta, w_o.y / med.eta, -cos_i),
                "inv_cos_i": 1.0 / dr.maximum(cos_i, 1e-6)}

    def _subsurface_image(self, result, key: int):
        """The fixed-point accumulation image for subsurface light of depth class ``key``."""
        mi, dr = self._mi, self._dr
        if key not in result.subsurface:
            result.subsurface[key] = dr.zeros(mi.UInt32, self.shape[0] * self.shape[1])
        return result.subsurface[key]

    def _nee_splat(self, x, d, w, act, med, conn, u, lane, target):
        """Next-event estimation through the plane boundary from walk vertex x.

        The walk's constants are gathered by its lane; the splat goes to the fixed-point
        image.
        """
        mi, dr = self._mi, self._dr

        def get(v):
            return dr.gather(type(v), v, lane, act)

        w_i = get(conn["w_i"])
        path = x.z * get(conn["inv_cos_i"])
        ex, ey = x.x + path * w_i.x, x.y + path * w_i.y
        sigma_t = get(med.sigma_s) + get(med.sigma_a)
        value = w * hg_eval(dr, get(med.g), dr.dot(d, w_i)) * dr.exp(-sigma_t * path) * get(conn["k"])
        uv = get(conn["uv0"]) + get(conn["ju"]) * ex + get(conn["jv"]) * ey
        fixed = mi.UInt32(dr.minimum(value + u, 4.0e9))
        iu = mi.Int32(dr.floor(uv.x + 0.5))
        iv = mi.Int32(dr.floor(uv.y + 0.5))
        rows, cols = self.shape
        ok = act & (iu >= 0) & (iu < cols) & (iv >= 0) & (iv < rows) & (fixed > 0)
        dr.scatter_reduce(dr.ReduceOp.Add, target, fixed, mi.UInt32(iv * cols + iu), ok)

    # ------------------------------------------------------------ continuation
    def _next(self, si, wo, weight, entered, beta, beta0, path_id, depth, s, active):
        """Next segment of every surviving path (surface bounces + medium exits), compacted."""
        mi, dr = self._mi, self._dr
        o, d, b, alive = self._continue(si, wo, weight, entered, self._exits, beta, beta0, path_id,
                                        depth, s, active)
        dr.eval(o, d, b, alive)  # one kernel for the gathers below (each would evaluate its source)
        idx = dr.compress(alive)
        ray = mi.Ray3f(dr.gather(mi.Point3f, o, idx), dr.gather(mi.Vector3f, d, idx))
        return (ray, dr.gather(mi.Float, b, idx), dr.gather(mi.Float, beta0, idx),
                dr.gather(mi.UInt32, path_id, idx), dr.full(mi.Bool, True, dr.width(idx)))

    def _continue(self, si, wo, weight, entered, exits, beta, beta0, path_id, depth, s, active):
        """Next segment of each path (surface bounce or medium exit), thinning, Russian roulette.

        ``depth`` is a Python int (wavefront) or a ``mi.UInt32`` (fused loop, depth ≥ 2: no
        thinning; the roulette where depth + 1 > ``rr_depth``, the same values).  Returns
        (origin, direction, power, alive) of every lane.
        """
        mi, dr = self._mi, self._dr
        surface = active & ~entered & (weight > 0)
        beta_s = beta * weight
        origin = si.spawn_ray(wo)
        o, d, b = origin.o, origin.d, beta_s
        alive = surface
        if exits is not None:
            out, exit_p, exit_d, exit_w = exits
            o = dr.select(out, exit_p, o)
            d = dr.select(out, exit_d, d)
            b = dr.select(out, exit_w, b)
            alive |= out
        if isinstance(depth, int) and depth == 1 and self.thinning > 1:
            m = self.thinning
            pick = mi.sample_tea_32(path_id // m, s ^ mi.UInt32(0x2545F491), 6)[0] % m
            alive &= (path_id % m) == pick
            b = b * float(m)
        if not isinstance(depth, int):
            rr = depth + 1 > self.rr_depth
            q = dr.minimum(b / dr.maximum(beta0, 1e-30), 0.95)
            keep = self._rand(s, path_id, depth, 7) < q
            alive &= keep | ~rr
            b = dr.select(rr, b / dr.maximum(q, 1e-30), b)
        elif depth + 1 > self.rr_depth:
            q = dr.minimum(b / dr.maximum(beta0, 1e-30), 0.95)
            keep = self._rand(s, path_id, depth, 7) < q
            alive &= keep
            b = b / dr.maximum(q, 1e-30)
        return o, d, b, alive

    def subsurface_electrons(self, result: TransportResult) -> dict:
        """The fixed-point subsurface images as (rows, columns) float32 electrons.

        Parameters
        ----------
        result : TransportResult
            From :meth:`trace` (its images are converted in place).

        Returns
        -------
        dict
            {1: first-surface subsurface light, 2: secondary} (only those present).
        """
        out = {}
        for key, img in result.subsurface.items():
            if isinstance(img, np.ndarray):
                out[key] = img.astype(np.float32, copy=False)
                continue
            a = np.asarray(img).reshape(self.shape).astype(np.float32)
            out[key] = a * np.float32(1.0 / FIXED_POINT_SCALE)
        result.subsurface = out
        return out



_TABLES: dict = {}
#: Media whose tables (and their kernels) one process keeps; a new medium beyond them empties the
#: caches (an identification renders a medium of its own per run: unbounded, they grew 0.2–0.3 GB a run).
MAX_CACHED_MEDIA = 4


def _table_for(medium):
    """The (cached, per process) :class:`SubsurfaceTable` of a medium, or None if g ≠ 0.

    At most :data:`MAX_CACHED_MEDIA` media are kept: a new one beyond them empties this cache and the
    kernels built from its tables (keyed by the table's ``id``, which a new table may reuse), so a
    process's memory does not grow with the media it has rendered.  Each kernel is built from its
    key alone: a frame does not depend on what was cached before.
    """
    from .subsurface import SubsurfaceTable

    if medium.g != 0.0:
        return None
    if medium not in _TABLES:
        if len(_TABLES) >= MAX_CACHED_MEDIA:
            _TABLES.clear()
            _SENSOR_KERNELS.clear()
            _SURFACE_KERNELS.clear()
        _TABLES[medium] = SubsurfaceTable(medium)
    return _TABLES[medium]


def _convolve_groups(img, geo, tables, electrons_per_watt, coarse: bool = False) -> None:
    """Add the tabulated subsurface light of the hits ``geo`` to ``img`` [e⁻].

    ``geo`` holds the columns of ``_entry_geometry``; per (16-px tile, part) group the
    entry image is convolved with the response on the sensor.  ``coarse`` (for the
    dim, spread-out light arriving after a bounce): 64-px tiles and the coarse kernel
    quantisation of :func:`_cached_sensor_kernel`.
    """
    size = 64.0 if coarse else 16.0
    part = geo[0].astype(np.int64)
    tile = (np.floor(geo[3] / size).astype(np.int64) * 100000
            + np.floor(geo[2] / size).astype(np.int64))
    order = np.lexsort((tile, part))
    keys = np.stack([part[order], tile[order]], 1)
    starts = np.flatnonzero(np.r_[True, np.any(np.diff(keys, axis=0) != 0, axis=1)])
    ends = np.r_[starts[1:], len(order)]
    w_sorted = geo[1, order]
    totals = np.add.reduceat(w_sorted, starts)
    means = np.add.reduceat(geo[:, order] * w_sorted, starts, axis=1) \
        / np.where(totals > 0, totals, 1.0)
    u_sorted, v_sorted = geo[2, order], geo[3, order]
    scaled = w_sorted * electrons_per_watt
    for g, (a, b) in enumerate(zip(starts, ends)):
        if totals[g] <= 0:
            continue
        mean = means[:, g]
        psi_in = math.atan2(mean[11], mean[10])      # forward direction of the incidence plane
        psi_view = math.atan2(mean[13], mean[12])
        azim = math.degrees(psi_view - psi_in)
        c, s_ = math.cos(psi_in), math.sin(psi_in)    # incidence frame → (b1, b2)
        j = mean[4:8]
        jac = (j[0] * c + j[2] * s_, j[1] * c + j[3] * s_, -j[0] * s_ + j[2] * c,
               -j[1] * s_ + j[3] * c)
        table = tables[int(keys[a, 0])]
        image_kernel, r0, c0 = _cached_sensor_kernel(table, math.degrees(mean[8]),
                                                     math.degrees(mean[9]), azim, jac, coarse)
        if image_kernel is None:
            continue
        _splat_convolved(img, u_sorted[a:b], v_sorted[a:b], scaled[a:b], image_kernel, r0, c0)


_SENSOR_KERNELS: dict = {}
_SURFACE_KERNELS: dict = {}


def _cached_sensor_kernel(table, incidence_deg, view_deg, azimuth_deg, jac, coarse=False):
    """Cached :func:`_sensor_kernel` of a table's response.

    Keyed by the angles (incidence, view, azimuth to 1°, 2.5°, 10°; ``coarse``: 5°, 5°,
    30°) and the Jacobian (to 2 %; ``coarse``: 10 %); the surface response of the
    angles is cached on its own (:func:`_surface_kernel`).
    """
    steps = (5.0, 5.0, 30.0, 10.0) if coarse else (1.0, 2.5, 10.0, 50.0)
    angles = (round(incidence_deg / steps[0]) * steps[0], round(view_deg / steps[1]) * steps[1],
              round(azimuth_deg / steps[2]) * steps[2])
    level = round(math.log(max(max(abs(float(x)) for x in jac), 1e-9)) * steps[3])
    scale = math.exp(level / steps[3])
    shape = tuple(round(float(x) / scale * steps[3]) for x in jac)
    key = (id(table), *angles, *shape, level)
    if key not in _SENSOR_KERNELS:
        # built from the key alone, so that a frame does not depend on the frames before
        jac = np.array(shape, np.float64) / steps[3] * scale
        merge = _merge_factor(table, scale)
        if len(_SENSOR_KERNELS) > 20000:
            _SENSOR_KERNELS.clear()
        skey = (id(table), *angles, merge)
        if skey not in _SURFACE_KERNELS:
            if len(_SURFACE_KERNELS) > 4000:
                _SURFACE_KERNELS.clear()
            _SURFACE_KERNELS[skey] = _surface_kernel(_serial(table.kernel, *angles, merge))
        kern, lo, half = _SURFACE_KERNELS[skey]
        _SENSOR_KERNELS[key] = _sensor_kernel(kern, lo, half, table.cell_mm * merge, jac)
    return _SENSOR_KERNELS[key]


def _serial(fn, *args):
    """``fn(*args)`` with numba's parallel loops on this thread alone (restored after).

    A table's view projection (:func:`sim.subsurface._project_table`) is a parallel loop
    of ≈ 0.3 ms: on two busy cores its threads cost more than they gain (0.74 against
    1.48 ms CPU, 2.0 against 3.5 ms wall per kernel at load 9); its rows are summed in a
    fixed order, so the kernel is the same.
    """
    before = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        return fn(*args)
    finally:
        numba.set_num_threads(before)


def _merge_factor(table, px_per_mm: float) -> int:
    """Merge factor of a table's cells per axis for a Jacobian scale [px/mm].

    The largest power of two (≤ NX/16) with merged cells ≤ ½ px.
    """
    merge = 1
    while 2 * merge * table.cell_mm * px_per_mm <= 0.5 and 2 * merge <= table.NX // 16:
        merge *= 2
    return merge


def _surface_kernel(kern):
    """A table kernel cropped to the box that holds all but its faint tail.

    The box leaves out at most 0.1 % of the light on each of its four sides (the far
    tail of the halo); the cells in it are scaled to hold all the light.  Returns (the
    cropped cells (x, y), index (x, y) of the crop's first cell in the kernel, index of
    the kernel's centre — the entry point); the cells are None when the kernel holds no
    light.
    """
    n = kern.shape[0]
    total = float(kern.sum())
    if total <= 0:
        return None, (0, 0), 0.5 * (n - 1)
    lo, hi = [], []
    for marginal in (kern.sum(axis=1), kern.sum(axis=0)):
        c = np.cumsum(marginal) / total
        lo.append(int(np.searchsorted(c, 0.001, side="right")))
        hi.append(max(int(np.searchsorted(c, 0.999, side="left")) + 1, lo[-1] + 1))
    crop = kern[lo[0]:hi[0], lo[1]:hi[1]]
    crop = crop * (total / max(float(crop.sum()), 1e-300))
    return np.ascontiguousarray(crop, np.float32), (lo[0], lo[1]), 0.5 * (n - 1)


def _sensor_kernel(kern, lo, half, cell_mm, jac):
    """Map a cropped surface response onto pixels.

    ``kern`` holds cells of ``cell_mm`` (x forward, y across; cell (i, j) of it is cell
    (lo + (i, j)) of a kernel centred at index ``half`` on the entry point), resampled on
    the pixel grid through the inverse of the local Jacobian ``jac`` = (∂u/∂x, ∂v/∂x,
    ∂u/∂y, ∂v/∂y) [px/mm].  Returns (kernel (rows, columns), row and column of the entry
    point in it), or (None, 0, 0).
    """
    det = jac[0] * jac[3] - jac[2] * jac[1]
    if kern is None or abs(det) < 1e-12:
        return None, 0, 0
    rows, cols = kern.shape
    x0, x1 = (lo[0] - half - 1) * cell_mm, (lo[0] + rows - half) * cell_mm
    y0, y1 = (lo[1] - half - 1) * cell_mm, (lo[1] + cols - half) * cell_mm
    du = (jac[0] * x0 + jac[2] * y0, jac[0] * x1 + jac[2] * y0, jac[0] * x0 + jac[2] * y1,
          jac[0] * x1 + jac[2] * y1)
    dv = (jac[1] * x0 + jac[3] * y0, jac[1] * x1 + jac[3] * y0, jac[1] * x0 + jac[3] * y1,
          jac[1] * x1 + jac[3] * y1)
    c0, r0 = math.ceil(-min(du)) + 1, math.ceil(-min(dv)) + 1
    out = np.zeros((math.ceil(max(dv)) + r0 + 2, math.ceil(max(du)) + c0 + 2))
    inv = np.array([jac[3], -jac[1], -jac[2], jac[0]]) / det   # (∂x/∂u, ∂y/∂u, ∂x/∂v, ∂y/∂v)
    _resample(out, r0, c0, kern.astype(np.float64) / (cell_mm * cell_mm), half - lo[0], half - lo[1], cell_mm, inv,
              1.0 / abs(det))
    total = out.sum()
    return (out * (float(kern.sum(dtype=np.float64)) / total) if total > 0 else out), r0, c0


@numba.njit(cache=True, nogil=True)
def _resample(out, r0, c0, density, hx, hy, cell_mm, inv, pixel_area):  # pragma: no cover
    """out[r, c] = density at the surface point of pixel offset (c − c0, r − r0) × pixel area.

    The entry point is at index (hx, hy) of ``density``; outside it the density is 0.
    """
    nx, ny = density.shape
    for r in range(out.shape[0]):
        dv = r - r0
        for c in range(out.shape[1]):
            du = c - c0
            fx = (inv[0] * du + inv[2] * dv) / cell_mm + hx
            fy = (inv[1] * du + inv[3] * dv) / cell_mm + hy
            ix, iy = int(math.floor(fx)), int(math.floor(fy))
            if ix < -1 or iy < -1 or ix >= nx or iy >= ny:
                continue
            ax, ay = fx - ix, fy - iy
            v = 0.0
            for dx in range(2):
                qx = ix + dx
                if qx < 0 or qx >= nx:
                    continue
                for dy in range(2):
                    qy = iy + dy
                    if 0 <= qy < ny:
                        v += (ax if dx else 1.0 - ax) * (ay if dy else 1.0 - ay) * density[qx, qy]
            out[r, c] = pixel_area * v


@numba.njit(cache=True, nogil=True)
def _splat_convolved(img, u, v, w, kern, r0, c0):  # pragma: no cover - compiled
    """Img += (entry image of the hits, bilinear at their images (u, v), weights w) ⊛ kern."""
    rows, cols = img.shape
    kr, kc = kern.shape
    u_lo, v_lo = int(math.floor(u.min())), int(math.floor(v.min()))
    entry = np.zeros((int(math.floor(v.max())) - v_lo + 2, int(math.floor(u.max())) - u_lo + 2))
    for i in range(u.shape[0]):
        fu, fv = math.floor(u[i]), math.floor(v[i])
        au, av = u[i] - fu, v[i] - fv
        iu, iv = int(fu) - u_lo, int(fv) - v_lo
        entry[iv, iu] += w[i] * (1.0 - av) * (1.0 - au)
        entry[iv, iu + 1] += w[i] * (1.0 - av) * au
        entry[iv + 1, iu] += w[i] * av * (1.0 - au)
        entry[iv + 1, iu + 1] += w[i] * av * au
    for er in range(entry.shape[0]):
        for ec in range(entry.shape[1]):
            e = entry[er, ec]
            if e == 0.0:
                continue
            top, left = v_lo + er - r0, u_lo + ec - c0
            for a in range(kr):
                r = top + a
                if r < 0 or r >= rows:
                    continue
                for b in range(kc):
                    c = left + b
                    if 0 <= c < cols:
                        img[r, c] += e * kern[a, b]
