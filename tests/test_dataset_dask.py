"""`scheimpflug dataset` on Dask: one LocalCluster on loopback (127.0.0.1) shared by the module.

1 worker in this process and 2 Dask workers give byte-identical datasets; a run killed
with SIGKILL (the whole process tree) resumes to the same hashes with no temporary file
left; a sample whose part file is missing is recorded while the rest complete; scoring
on the cluster equals scoring here.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

SPEC = """
[dataset]
seed = 11
samples = 4
[rig]
preset = "paper"
[rig.variation]
"sensor.offset_u_px" = [-3.0, 3.0]
[scenario]
kind = "rotary"
part = "sphere"
step_deg = 60.0
frames = 3
binning = 8
[scenario.variation]
material = { choices = ["metal", "cardboard"] }
"""


@pytest.fixture(scope="module")
def cluster():
    import dask
    from distributed import LocalCluster

    dask.config.set({"distributed.worker.multiprocessing-method": "spawn"})
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address="127.0.0.1:0", silence_logs=40) as lc:
        assert lc.scheduler_address.startswith("tcp://127.0.0.1:")
        yield lc.scheduler_address


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The spec made in this process (1 worker)."""
    from sim.dataset import load_spec, make_dataset

    base = tmp_path_factory.mktemp("dask")
    (base / "spec.toml").write_text(SPEC)
    make_dataset(load_spec(base / "spec.toml"), base / "one")
    return base


def _hashes(out: Path) -> tuple:
    import pyarrow.parquet as pq

    index = pq.read_table(out / "index.parquet").to_pylist()
    files = pq.read_table(out / "files.parquet").to_pylist()
    return ([(r["sample"], r["frame"], r["file"], r["sha256"], r["truth_sha256"]) for r in index],
            sorted((f["path"], f["sha256"]) for f in files))


def _leftovers(out: Path) -> list:
    return [p for p in out.rglob("*") if p.name.endswith(".partial") or ".tmp" in p.name]


def test_two_dask_workers_make_the_same_bytes_as_one(reference, cluster):
    from sim.dataset import load_spec, make_dataset

    calls = []
    res = make_dataset(load_spec(reference / "spec.toml"), reference / "two", scheduler=cluster,
                       progress=lambda d, t: calls.append((d, t)))
    assert res.complete and res.frames == 12
    assert _hashes(reference / "two") == _hashes(reference / "one")  # exact: threads
    assert calls[-1] == (12, 12)
    assert all(d <= t == 12 for d, t in calls)
    assert [d for d, _ in calls] == sorted(d for d, _ in calls)


def test_sigkill_of_the_whole_tree_then_rerun_gives_identical_hashes(reference):
    out = reference / "killed"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-m", "scheimpflug", "dataset", "make",
                             str(reference / "spec.toml"), "--out", str(out), "--workers", "2", "--quiet"],
                            env=env, start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    try:
        while time.monotonic() < deadline and proc.poll() is None:
            if list(out.glob("samples/.*.partial/frames/*.png")):     # some frames written
                break
            time.sleep(0.02)
        assert proc.poll() is None, "the run ended before it could be killed"
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    time.sleep(0.5)                                  # let killed workers vanish
    assert not (out / "samples" / "000003" / "sample.json").exists()   # killed part-way
    res = subprocess.run([sys.executable, "-m", "scheimpflug", "dataset", "make",
                          str(reference / "spec.toml"), "--out", str(out), "--json", "--quiet"],
                         env=env, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    summary = json.loads(res.stdout)
    assert summary["complete"] and summary["frames"] == 12
    assert _hashes(out) == _hashes(reference / "one")  # exact: resume
    assert _leftovers(out) == []


def test_missing_part_file_is_recorded_and_the_rest_complete(reference, cluster, tmp_path):
    from sim.dataset import load_spec, make_dataset

    # a part file that exists but cannot be read fails its samples only (a missing file is refused
    # at the spec, before any sample: tests/test_hostile_dataset.py)
    spec = tmp_path / "spec.toml"
    (tmp_path / "parts").mkdir()
    (tmp_path / "parts" / "missing.stl").write_bytes(b"solid nothing\nthis is not a mesh\n")
    spec.write_text(SPEC.replace('part = "sphere"', "").replace(
        'material = { choices = ["metal", "cardboard"] }',
        'part = { choices = ["sphere", "parts/missing.stl"] }'))
    warnings = []
    res = make_dataset(load_spec(spec), tmp_path / "out", scheduler=cluster, warn=warnings.append)
    plans = json.loads((tmp_path / "out" / "dataset.json").read_text())
    failed = {f["sample"] for f in res.failures}
    assert failed and len(failed) < 4
    assert all("missing.stl" in f["error"] for f in res.failures)
    assert plans["failures"] == res.failures and plans["complete"] is False
    assert res.samples_done == 4 - len(failed)
    assert any("tried again" in w for w in warnings)
    from scheimpflug.dataset import open_dataset, verify_dataset

    ds = open_dataset(tmp_path / "out")
    assert set(ds.samples) == set(range(4)) - failed
    assert all(r["part"] == "sphere" for r in ds.rows())
    assert verify_dataset(tmp_path / "out").ok


def test_scoring_on_the_cluster_equals_scoring_here(reference, cluster):
    from scheimpflug.dataset import open_dataset, score_dataset
    from sim.dataset import Engine

    ds = open_dataset(reference / "one")
    here = score_dataset(ds, "gaussian3").to_json()
    with Engine(scheduler=cluster) as engine:
        def run(fn, items):
            for _, res in engine.map(lambda item, progress=None, threads=None: fn(item), items):
                assert not isinstance(res, BaseException), res
                yield res

        there = score_dataset(ds, "gaussian3", map_fn=run).to_json()
    assert there == here and here["n_rows"] > 100


def test_a_killed_worker_loses_only_its_frames_in_flight(reference, cluster):
    """SIGKILL one Dask worker mid-sample: Dask reruns its task elsewhere, which resumes the
    sample's partial folder; the result is byte-identical and nothing temporary is left.
    """
    import threading

    from distributed import Client

    from sim.dataset import load_spec, make_dataset

    out = reference / "one-killed"
    result = {}
    job = threading.Thread(target=lambda: result.update(
        res=make_dataset(load_spec(reference / "spec.toml"), out, scheduler=cluster)))
    with Client(cluster) as client:
        pids = client.run(os.getpid)
        job.start()
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not list(out.glob("samples/.*.partial/frames/*.png")):
            time.sleep(0.02)
        os.kill(next(iter(pids.values())), signal.SIGKILL)
        job.join(timeout=300)
    assert not job.is_alive()
    assert result["res"].complete and not result["res"].failures
    assert _hashes(out) == _hashes(reference / "one")  # exact: resume
    assert _leftovers(out) == []


def test_a_missing_part_file_added_later_is_made_on_rerun(reference, cluster, tmp_path):
    """The remedy for a missing part file: provide the file and rerun the same command (the first
    run is refused at the spec, before anything is written)."""
    from scheimpflug.errors import DatasetError
    from sim.dataset import load_spec, make_dataset

    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC.replace('part = "sphere"', "").replace(
        'material = { choices = ["metal", "cardboard"] }',
        'part = { choices = ["sphere", "late.ply"] }'))
    with pytest.raises(DatasetError, match=r"part 'late.ply': no such file"):
        load_spec(spec)
    assert not (tmp_path / "out").exists()
    from scenes import load_part

    load_part("sphere").to_ply(tmp_path / "late.ply")
    second = make_dataset(load_spec(spec), tmp_path / "out", scheduler=cluster)
    assert second.complete and second.samples_made == 4
