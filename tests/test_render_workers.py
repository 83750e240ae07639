"""Frames of one render in several worker processes (sim.workers, ``render --workers N``).

Same folder with 1 and 2 workers, byte for byte (the analytic fake twin, the ideal
Mitsuba twin and the realistic one: 3 bounces, subsurface, surface speckle, on a
16 × 16 binned sensor); a worker's failure names the frame and leaves only complete
frames; a dying worker is reported, not waited for; the interrupted run resumes to
the same files.
"""

import hashlib
import os
from concurrent.futures import Future
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from test_render_cli import FakeTwin

from scheimpflug.errors import RenderError
from scheimpflug.io.folder import FileLedger
from scheimpflug.model.binning import binned_rig
from scheimpflug.model.rig import load_preset
from sim.workers import RenderJob, _FrameResult, _pool_loop, render_with_workers
from sim.writer import RenderStats, render_folder

FAIL_AT = 4


class Fake(FakeTwin):
    """The analytic fake twin, built as the workers build a twin."""

    def __init__(self, rig, assembly, spp=None):
        super().__init__(rig, assembly)
        self.spp, self.variant = 1, "fake"


class FailingTwin(Fake):
    """Raises on frame FAIL_AT."""

    def render(self, frame):
        if frame.index == FAIL_AT:
            raise ValueError("injected failure")
        return super().render(frame)


class DyingTwin(Fake):
    """The worker process ends abruptly on frame FAIL_AT."""

    def render(self, frame):
        if frame.index == FAIL_AT:
            os._exit(3)
        return super().render(frame)


def _files(folder: Path) -> dict:
    """Every file of a frame folder (lock excluded) → SHA-256 of its bytes."""
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file() and p.name != ".scheimpflug.lock"}


def _job(factory=Fake, frames=8):
    rig = binned_rig(load_preset("paper"), 8)
    return RenderJob(rig, "blocker", seed=3, options={"frames": frames, "truth_pixels_every": 3},
                     twin_factory=factory)


def test_fake_twin_one_and_two_workers_write_the_same_folder(tmp_path):
    job = _job()
    render_with_workers(job, tmp_path / "w1", 1, warn=lambda m: None)
    progress = []
    stats, _ = render_with_workers(job, tmp_path / "w2", 2, warn=lambda m: None,
                                   progress=lambda d, t: progress.append((d, t)))
    one, two = _files(tmp_path / "w1"), _files(tmp_path / "w2")
    assert len([k for k in one if k.startswith("frames/")]) == 8
    assert one == two
    assert stats.frames_rendered == 8 and progress[-1] == (8, 8)
    assert [d for d, _ in progress] == list(range(9))


def _leftovers(folder: Path) -> list:
    return [p.name for p in folder.rglob("*") if ".tmp" in p.name]


DIED = r"ended unexpectedly \(exit code 3\b.*while frames [0-9–, ]+ were in flight"


@pytest.mark.parametrize("factory, message", [(FailingTwin, "frame 4 .*injected failure"),
                                               (DyingTwin, DIED)])
def test_a_failing_worker_names_the_frame_and_the_run_resumes(tmp_path, factory, message):
    out = tmp_path / "run"
    with pytest.raises(RenderError, match=message):
        render_with_workers(_job(factory), out, 2, warn=lambda m: None)
    assert _leftovers(out) == []
    ledger = FileLedger(out)
    written = sorted(int(p.stem) for p in (out / "frames").glob("*.png"))
    assert FAIL_AT not in written
    for i in written:     # every frame there is complete and recorded
        assert ledger.mismatch(i, [f"frames/{i:05d}.png", f"truth/{i:05d}.npz"]) is None
    stats, _ = render_with_workers(_job(), out, 2, warn=lambda m: None)
    assert stats.frames_skipped == len(written)
    render_with_workers(_job(), tmp_path / "clean", 1, warn=lambda m: None)
    assert _files(out) == _files(tmp_path / "clean")  # exact: resume


class _BreakingExecutor:
    """Hands out finished frames, then breaks as a pool whose worker died between two results."""

    def __init__(self, good: int):
        self.good = good

    def submit(self, fn, index):
        if self.good == 0:
            raise BrokenProcessPool("A child process terminated abruptly")
        self.good -= 1
        fut = Future()
        fut.set_result(_FrameResult(index, b"npz", b"png", {}, False, []))
        return fut


class _BreakingPool:
    workers = 1

    def __init__(self, good: int):
        self.executor = _BreakingExecutor(good)

    def _exit_codes(self) -> str:
        return "exit code 9"


class _Ledger:
    def __init__(self):
        self.recorded = []

    def record(self, index, names):
        self.recorded.append(index)


class _Bar:
    def update(self):
        pass


def test_a_worker_dying_between_results_is_the_same_error(tmp_path):
    """The pool can break while the main process writes a result: the next hand-out says so (CI saw it)."""
    for sub in ("frames", "truth"):
        (tmp_path / sub).mkdir()
    frames = [SimpleNamespace(index=i) for i in range(6)]
    ledger = _Ledger()
    with pytest.raises(RenderError, match=r"ended unexpectedly \(exit code 9\b.*while frames 1 were in flight"):
        _pool_loop(_BreakingPool(2), tmp_path, lambda m: None, frames, RenderStats(), _Bar(), ledger)
    assert ledger.recorded == [0]      # frame 0 written whole before the error
    assert (tmp_path / "frames" / "00000.png").read_bytes() == b"png"      # exact: copy of the bytes


@pytest.mark.parametrize("realistic", [False, True], ids=["ideal", "realistic"])
def test_mitsuba_twin_one_and_two_workers_write_the_same_folder(tmp_path, realistic):
    rig = binned_rig(load_preset("paper"), 16)
    if realistic:
        rig = rig.replace(twin={"bounces": 3, "subsurface": True}, laser={"speckle_contrast": 0.7})
    opts = {"part": "pile", "step_deg": 7.0, "frames": 4, "truth_pixels_every": 3}
    stats1, m1 = render_folder(rig, "rotary", tmp_path / "w1", seed=5, warn=lambda m: None, **opts)
    stats2, m2 = render_folder(rig, "rotary", tmp_path / "w2", seed=5, warn=lambda m: None,
                               workers=2, **opts)
    assert m1 == m2
    assert stats2.frames_rendered == 4
    one, two = _files(tmp_path / "w1"), _files(tmp_path / "w2")
    assert "frames/00003.png" in one and "truth/00003.npz" in one
    assert one == two


def test_auto_workers_one_per_core_for_a_long_realistic_job_only():
    from sim.workers import AUTO_MIN_PIXELS, auto_workers

    ideal = load_preset("paper")
    real = ideal.replace(twin={"bounces": 3})
    frames = -(-AUTO_MIN_PIXELS // (ideal.sensor.rows * ideal.sensor.columns))
    assert auto_workers(real, frames, n_cores=2) == 2
    assert auto_workers(real, frames - 1, n_cores=2) == 1
    assert auto_workers(binned_rig(real, 8), frames, n_cores=2) == 1     # 64× fewer pixels
    assert auto_workers(ideal, 10 * frames, n_cores=2) == 1
    assert auto_workers(ideal.replace(laser={"speckle_contrast": 0.5}), frames, n_cores=4) == 4
    assert auto_workers(real, frames, n_cores=8, worker_bytes=4e9, ram_bytes=24e9) == 3


def test_cli_refuses_a_bad_workers_value(tmp_path, capsys):
    from scheimpflug.app.cli import main

    assert main(["render", "blocker", "--workers", "0", "--out", str(tmp_path / "o")]) == 2
    assert "--workers" in capsys.readouterr().err


def test_ray_queries_compile_once_for_any_ray_count_and_pose():
    """No ray count, pose or input alignment is baked into the ray-query kernels (one
    compilation for a whole scan, not one per frame), and the values are unchanged."""
    import drjit as dr
    import mitsuba as mi
    import trimesh

    from sim.scene import SimScene, dr_vector, numpy_rows
    from sim.variant import is_jit_variant, select_variant

    if not is_jit_variant(select_variant()):
        pytest.skip("no usable libLLVM ≥ 17: the renderer needs a JIT variant")
    plate = trimesh.creation.box([5.0, 200.0, 120.0])
    scene = SimScene([(plate, "tape", 1)])

    def queries(n, x_mm):
        pose = np.eye(4)
        pose[:3, 3] = (x_mm, 0.0, 0.0)
        scene.set_pose(pose)
        rng = np.random.default_rng(n)
        d = np.column_stack([np.ones(n), rng.normal(0, 0.1, (n, 2))])
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        t, part, _ = scene.first_hit_parts(d)
        scene.first_hit(np.zeros((n - 1, 3)), d[1:])      # another count, another alignment
        assert np.isfinite(t).any() and (part == 0).any()
        return {k["hash"] for k in dr.kernel_history() if k.get("hash") is not None}

    flag = dr.flag(dr.JitFlag.KernelHistory)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()
        first = queries(1001, 600.0)
        later = queries(1377, 612.5) | queries(517, 590.0)
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, flag)
    assert later <= first
    a = np.random.default_rng(1).normal(size=(9, 3))
    v = dr_vector(mi, mi.Vector3f, a[1:])
    dr.eval(v)
    assert np.array_equal(numpy_rows(v, np.float64), np.asarray(mi.Vector3f(a[1:].T.astype(np.float32)),  # exact: copy
                                                                 np.float64))
