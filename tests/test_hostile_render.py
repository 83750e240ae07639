"""Hostile cases of the frame folder writer (issue 12): concurrent writers, verified resume, full disk.

A fake twin (the analytic stripe of ``test_render_cli.FakeTwin``) on an 8 × 8 binned
sensor keeps these cheap; one test runs two real renders at once.
"""

import errno
import json
import multiprocessing
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_render_cli import FakeTwin, _digest

from scheimpflug.errors import RenderError
from scheimpflug.io.folder import LEDGER_NAME, LOCK_NAME, FileLedger, FolderLock
from scheimpflug.model.binning import binned_rig
from scheimpflug.model.rig import load_preset
from sim.scenarios import blocker_scenario
from sim.writer import build_manifest, render_scenario

ROOT = Path(__file__).resolve().parents[1]


def _rig():
    return binned_rig(load_preset("paper"), 8)


def _render(out, seed=1, frames=3, twin=None, warn=None):
    rig = _rig()
    sc = blocker_scenario(rig, seed=seed, frames=frames, truth_pixels_every=0)
    twin = twin or FakeTwin(rig, sc.assembly)
    manifest = build_manifest(rig, sc, seed, spp=1, variant="fake")
    stats = render_scenario(rig, sc, out, twin, manifest, warn=warn or (lambda m: None))
    return twin, stats


class SlowTwin(FakeTwin):
    """The fake twin, 10 ms per frame: two runs started together overlap."""

    def render(self, frame):
        time.sleep(0.01)
        return super().render(frame)


def _writer(seed, barrier, tasks, results):
    """A writer process (spawned once): for each folder it is given, wait for the other, render."""
    rig = _rig()
    sc = blocker_scenario(rig, seed=seed, frames=2, truth_pixels_every=0)
    manifest = build_manifest(rig, sc, seed, spp=1, variant="fake")
    while (out := tasks.get()) is not None:
        barrier.wait()
        try:
            render_scenario(rig, sc, out, SlowTwin(rig, sc.assembly), manifest, warn=lambda m: None)
            results.put((seed, "ok"))
        except RenderError as exc:
            results.put((seed, f"refused: {exc}"))
        except BaseException as exc:  # noqa: BLE001 - any other failure is what the test looks for
            results.put((seed, f"crash: {type(exc).__name__}: {exc}"))


def _frame_hashes(folder):
    return FileLedger(folder).records


def test_concurrent_writers_twenty_trials_never_mix_a_folder(tmp_path):
    """Item 1: two writers with different seeds into one new folder, 20 times: one folder, one run."""
    ref = {}
    for seed in (1, 2):
        _render(tmp_path / f"ref{seed}", seed=seed, frames=2)
        ref[seed] = _frame_hashes(tmp_path / f"ref{seed}")
    assert ref[1] != ref[2]
    ctx = multiprocessing.get_context("spawn")     # two processes, started once (fork is unsafe
    barrier, results = ctx.Barrier(2), ctx.Queue()  # after OpenMP threads exist)
    tasks = {seed: ctx.Queue() for seed in (1, 2)}
    procs = [ctx.Process(target=_writer, args=(seed, barrier, tasks[seed], results)) for seed in (1, 2)]
    for p in procs:
        p.start()
    try:
        outcomes = [_trial(tmp_path / f"t{trial}", tasks, results, ref) for trial in range(20)]
    finally:
        for seed in (1, 2):
            tasks[seed].put(None)
        for p in procs:
            p.join(30)
    assert "busy" in outcomes        # the writers did overlap (the lock was what refused)


def _trial(out, tasks, results, ref) -> str:
    for seed in (1, 2):
        tasks[seed].put(out)
    got = dict(results.get(timeout=60) for _ in range(2))
    assert not any(v.startswith("crash") for v in got.values()), got
    winners = [s for s, v in got.items() if v == "ok"]
    assert len(winners) == 1, got          # the other is refused: busy, or another run
    loser = 3 - winners[0]
    assert "being written by" in got[loser] or "different run" in got[loser]
    m = json.loads((out / "manifest.json").read_text())
    assert m["seed"] == winners[0] and m["complete"] is True
    assert _frame_hashes(out) == ref[winners[0]]          # exact: same run; every file is the winner's run's
    for i in range(2):
        assert FileLedger(out).mismatch(i, [f"frames/{i:05d}.png", f"truth/{i:05d}.npz"]) is None
    assert not (out / LOCK_NAME).exists()
    return "busy" if "being written by" in got[loser] else "after"


def test_second_writer_is_refused_with_the_owner_named(tmp_path):
    out = tmp_path / "f"
    out.mkdir()
    with FolderLock(out):
        with pytest.raises(RenderError, match=rf"being written by pid {os.getpid()} on host"):
            _render(out)
        assert not (out / "manifest.json").exists()      # refused before touching anything
    twin, stats = _render(out)                           # released: the next run works
    assert stats.frames_rendered == 3 and not (out / LOCK_NAME).exists()


def test_stale_lock_of_a_dead_writer_is_taken_over(tmp_path):
    out = tmp_path / "f"
    out.mkdir()
    (out / LOCK_NAME).write_text(json.dumps({"pid": 999999, "host": "gone", "started": "x", "program": "y"}))
    warnings = []
    _render(out, warn=warnings.append)
    assert any("took over the lock" in w and "999999" in w for w in warnings)
    assert json.loads((out / "manifest.json").read_text())["complete"] is True
    assert not (out / LOCK_NAME).exists()


@pytest.mark.parametrize("damage", ["truncate-png", "truncate-npz", "flip-png-byte", "delete-ledger"])
def test_resume_verifies_what_it_skips(tmp_path, damage):
    """Items 2 and 'truncated truth/*.npz': a damaged frame is rendered again, not skipped."""
    _render(tmp_path / "ref")
    out = tmp_path / "f"
    _render(out)
    png, npz = out / "frames" / "00001.png", out / "truth" / "00001.npz"
    if damage == "truncate-png":
        os.truncate(png, 100)                                 # truncate -s 100 frames/00001.png
    elif damage == "truncate-npz":
        os.truncate(npz, 100)
    elif damage == "flip-png-byte":
        data = bytearray(png.read_bytes())
        data[len(data) // 2] ^= 0xFF
        png.write_bytes(bytes(data))                          # same size, other content
    else:
        (out / LEDGER_NAME).unlink()                          # a folder of an older version
    warnings = []
    twin, stats = _render(out, warn=warnings.append)
    expected = 3 if damage == "delete-ledger" else 1
    assert twin.calls == expected and stats.frames_skipped == 3 - expected
    assert any("rendering again" in w for w in warnings), warnings
    assert _digest(out) == _digest(tmp_path / "ref")  # exact: resume
    assert (out / LEDGER_NAME).read_bytes() == (tmp_path / "ref" / LEDGER_NAME).read_bytes()
    assert json.loads((out / "manifest.json").read_text())["complete"] is True


def test_disk_full_is_one_error_nothing_half_written_and_resumable(tmp_path, monkeypatch):
    import sim.writer as writer

    real, calls = writer._write_npz, []

    def full_disk(path, arrays):
        calls.append(path)
        if len(calls) == 2:
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        real(path, arrays)

    monkeypatch.setattr(writer, "_write_npz", full_disk)
    out = tmp_path / "full"
    with pytest.raises(RenderError, match=r"frame folder .*full.*No space left on device.*resume"):
        _render(out)
    assert not list(out.rglob(".*.tmp*")) and not (out / LOCK_NAME).exists()
    assert sorted(p.name for p in (out / "frames").iterdir()) == ["00000.png"]
    monkeypatch.setattr(writer, "_write_npz", real)
    twin, stats = _render(out)
    assert twin.calls == 2 and stats.frames_skipped == 1
    _render(tmp_path / "ref")
    assert _digest(out) == _digest(tmp_path / "ref")  # exact: resume


@pytest.mark.render
def test_two_real_renders_at_once_leave_one_run(tmp_path):
    """The real twin: two `scheimpflug render` processes into one folder; one wins, one line for the other."""
    out = tmp_path / "blk"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    cmd = [sys.executable, "-m", "scheimpflug", "render", "blocker", "--binning", "8", "--frames", "3",
           "--quiet", "--out", str(out)]
    procs = [subprocess.Popen(cmd + ["--seed", str(seed)], env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for seed in (1, 2)]
    done = [(p.wait(300), p.stderr.read()) for p in procs]
    codes = sorted(c for c, _ in done)
    assert codes == [0, 2], done
    err = next(e for c, e in done if c == 2).strip().splitlines()
    assert len(err) == 1 and ("being written by" in err[0] or "different run" in err[0]), err
    m = json.loads((out / "manifest.json").read_text())
    assert m["complete"] is True and m["seed"] == next(s for s, (c, _) in zip((1, 2), done) if c == 0)
    for i in range(3):
        assert FileLedger(out).mismatch(i, [f"frames/{i:05d}.png", f"truth/{i:05d}.npz"]) is None


def test_lock_without_flock_falls_back_to_exclusive_creation(tmp_path, monkeypatch):
    """File systems without flock(2): the lock file's existence is the lock; a dead owner's is stale."""
    import fcntl
    import socket

    def no_flock(fd, op):
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(fcntl, "flock", no_flock)
    first = FolderLock(tmp_path)
    first.acquire()
    with pytest.raises(Exception, match=rf"being written by pid {os.getpid()}"):
        FolderLock(tmp_path).acquire()
    first.release()
    assert not (tmp_path / LOCK_NAME).exists()
    (tmp_path / LOCK_NAME).write_text(json.dumps({"pid": 999999, "host": socket.gethostname()}))
    with FolderLock(tmp_path) as lock:                     # same host, pid gone: stale
        assert lock.stale_owner["pid"] == 999999
    (tmp_path / LOCK_NAME).write_text(json.dumps({"pid": 1, "host": "elsewhere"}))
    with pytest.raises(Exception, match="host 'elsewhere'"):  # another host: cannot tell, refused
        FolderLock(tmp_path).acquire()
