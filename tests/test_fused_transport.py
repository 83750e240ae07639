"""Issue 27: the fused transport loop and the pipelined frame loop.

* Depths 2 … N of the laser paths traced in one symbolic Dr.Jit loop
  (:meth:`sim.transport.LightTransport._fused_depths`) give the light of the wavefront
  loop (one set of kernels per depth, the code before issue 27) — inter-reflections and
  the tabulated subsurface light, within float32 rounding — in a handful of kernels, and
  a frame never rendered before compiles no new kernel (no per-frame literal in them).
* The pipelined frame loop (render and scene truth here, noise and writes of the frame
  before on a thread) writes the files of the sequential loop, byte for byte.
"""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from scheimpflug.model.binning import binned_rig
from scheimpflug.model.rig import load_preset

pytestmark = pytest.mark.render


def _realistic(k: int = 8):
    return binned_rig(load_preset("paper"), k).replace(
        twin={"bounces": 3, "subsurface": True}, laser={"speckle_contrast": 0.7})


@pytest.fixture(scope="module")
def pile_twin():
    from sim.scenarios import rotary_scenario
    from sim.writer import MitsubaTwin

    rig = _realistic()
    scenario = rotary_scenario(rig, part="pile", step_deg=37.0, frames=3, truth_pixels_every=0)
    return rig, scenario, MitsubaTwin(rig, scenario.assembly)


def _light(twin, frame, fused: bool):
    twin.renderer.transport.fused = fused
    try:
        return twin.renderer.render_light(frame.rig_from_part, frame.seed, frame.rig_from_laser)
    finally:
        twin.renderer.transport.fused = True


def test_fused_loop_gives_the_wavefront_light(pile_twin):
    _, scenario, twin = pile_twin
    for frame in scenario.frames[:2]:
        old, new = _light(twin, frame, False), _light(twin, frame, True)
        assert old.secondary.sum() > 0.01 * old.laser.sum()       # the bounces carry light
        assert old.walks[0] > 100 and new.walks == old.walks      # paths that entered media
        for name in ("image", "laser", "secondary", "subsurface", "coherent"):
            a, b = getattr(old, name), getattr(new, name)
            np.testing.assert_allclose(b, a, rtol=1e-5, atol=1e-6 * float(a.max()), err_msg=name)


def _transport_kernels(twin, frame, fused: bool) -> tuple[int, int]:
    """(JIT kernels of the transport beyond the first hit, of them compiled or loaded anew)."""
    import drjit as dr

    tr = twin.renderer.transport
    calls = []
    original = tr.trace

    def traced(*args):
        dr.kernel_history()                      # the first hit's kernels end here
        out = original(*args)
        calls.append([k for k in dr.kernel_history() if str(k["type"]).endswith("JIT")])
        return out

    dr.set_flag(dr.JitFlag.KernelHistory, True)
    tr.trace = traced
    try:
        _light(twin, frame, fused)
    finally:
        tr.trace = original
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    kernels = calls[0]
    return len(kernels), sum(1 for k in kernels if not k.get("cache_hit", True))


def test_fused_loop_runs_in_few_kernels_and_compiles_none_per_frame(pile_twin):
    _, scenario, twin = pile_twin
    first, second, third = scenario.frames
    _light(twin, first, True)                                   # compiles the loop once
    n_fused, new_fused = _transport_kernels(twin, second, True)  # a pose never rendered before
    n_wave, _ = _transport_kernels(twin, third, False)
    assert new_fused == 0, "the fused loop compiled a kernel for a new frame (a per-frame literal)"
    assert n_fused <= 8 < n_wave, (n_fused, n_wave)


def _folder_digest(root) -> dict:
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.suffix in (".png", ".npz")}


@pytest.mark.parametrize("realistic", [False, True])
def test_pipelined_frame_loop_writes_the_sequential_loop_files(tmp_path, realistic):
    from sim.scenarios import rotary_scenario
    from sim.writer import MitsubaTwin, build_manifest, generator_info, render_scenario

    rig = _realistic(16) if realistic else binned_rig(load_preset("paper"), 8)
    scenario = rotary_scenario(rig, part="pile", step_deg=23.0, frames=4, truth_pixels_every=0)
    twin = MitsubaTwin(rig, scenario.assembly)
    manifest = build_manifest(rig, scenario, 0, twin.spp, twin.variant, generator_info(),
                              twin.describe())
    digests = []
    for overlap in (False, True):
        out = tmp_path / f"overlap_{overlap}"
        render_scenario(rig, scenario, out, twin, manifest, warn=lambda m: None, overlap=overlap)
        digests.append(_folder_digest(out))
    # exact: threads (the pipelined loop: a second thread, Dr.Jit's pool at one thread; every
    # value computed by the same code, every accumulation ordered)
    assert len(digests[0]) == 8 and digests[1] == digests[0]
