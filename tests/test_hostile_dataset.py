"""Hostile use of `scheimpflug dataset` (issue 25): kills mid-sample, damaged files, a regression gate
that must not pass a detector that finds nothing, jobs too large to plan, failures on Dask, a full disk,
frames listed twice.

One small spec (the paper cylinder on the rotary stage, 4 × 4 binned, 2 samples of 12 frames) is made
once per format in this process: the reference every resumed or repaired dataset must equal byte for
byte (same seed, same configuration, same machine).
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from scheimpflug.errors import DatasetError
from scheimpflug.io.folder import LOCK_NAME

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.render

SPEC = """
[dataset]
seed = 3
samples = 2
[rig]
preset = "paper"
[scenario]
kind = "rotary"
part = "cylinder"
step_deg = 30.0
binning = 4
"""

DETECTORS = """
import os
import numpy as np

def nothing(frame):
    return np.full(frame.shape[0], np.nan)

def huge(frame):
    return np.full(frame.shape[0], 1e308)

def infinite(frame):
    return np.full(frame.shape[0], np.inf)

def boom(frame):
    raise ValueError("boom")

def dies(frame):
    os._exit(7)

def exits(frame):
    raise SystemExit(3)
"""


def _hashes(out: Path) -> tuple:
    """Every frame's and file's SHA-256 as the index and the ledger list them."""
    import pyarrow.parquet as pq

    index = pq.read_table(out / "index.parquet").to_pylist()
    files = pq.read_table(out / "files.parquet").to_pylist()
    return ([(r["sample"], r["frame"], r["file"], r["sha256"], r["truth_sha256"]) for r in index],
            sorted((f["path"], f["sha256"], f["bytes"]) for f in files))


def _leftovers(out: Path) -> list:
    return [p for p in out.rglob("*") if p.name.endswith(".partial") or ".tmp" in p.name
            or p.name in (LOCK_NAME, "checksums.jsonl")]


@pytest.fixture(scope="module")
def ref(tmp_path_factory, variant):
    """The spec made straight through in this process, as PNG and as Zarr."""
    from sim.dataset import load_spec, make_dataset

    base = tmp_path_factory.mktemp("hostile-ds")
    (base / "spec.toml").write_text(SPEC)
    (base / "dets.py").write_text(DETECTORS)
    spec = load_spec(base / "spec.toml")
    for storage in ("png", "zarr"):
        assert make_dataset(spec, base / storage, storage=storage).complete
    return base


def _make(base: Path, out: Path, **kwargs):
    from sim.dataset import load_spec, make_dataset

    warnings: list = []
    return make_dataset(load_spec(base / "spec.toml"), out, warn=warnings.append, **kwargs), warnings


#: a real `dataset make` in its own process, each frame's write delayed by 0.15 s so that a SIGKILL
#: lands inside sample 0 (the kill itself is real: nothing is cleaned up)
_SLOW_MAKE = textwrap.dedent("""
    import sys, time
    import sim.dataset.sample as sample
    real = sample._write_one
    def slow(*args):
        time.sleep(0.15)
        return real(*args)
    sample._write_one = slow
    from scheimpflug.app.cli import main
    sys.exit(main(sys.argv[1:]))
""")


def _killed_mid_sample(base: Path, out: Path, storage: str, marker: str) -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-c", _SLOW_MAKE, "dataset", "make", str(base / "spec.toml"),
                             "--out", str(out), "--format", storage, "--quiet"], env=env, start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    try:
        while time.monotonic() < deadline and proc.poll() is None and not (out / marker).exists():
            time.sleep(0.01)
        assert proc.poll() is None, "the run ended before it could be killed"
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    assert (out / "samples" / ".000000.partial").is_dir() and not (out / "samples" / "000000").exists()


# ------------------------------------------------------------------ kill -9 mid-sample


def test_zarr_dataset_killed_mid_sample_resumes_to_the_same_bytes(ref, tmp_path):
    """Before: every rerun failed with ``ValueError: invalid literal for int() … 'c.0.0'``, verify exit 1."""
    from scheimpflug.dataset import verify_dataset

    out = tmp_path / "zarr"
    _killed_mid_sample(ref, out, "zarr", "frames.zarr/frames/c.3.0.0")
    res, warnings = _make(ref, out, storage="zarr")
    assert res.complete and not res.failures, warnings
    assert res.frames_rendered < 24                     # the frames made before the kill are kept
    assert _hashes(out) == _hashes(ref / "zarr")  # exact: resume
    assert verify_dataset(out).ok and _leftovers(out) == []


def test_png_frame_damaged_in_a_partial_sample_is_rendered_again(ref, tmp_path):
    """kill -9 during sample 0, ``truncate -s 100`` a finished frame of the partial sample, rerun:
    before, the 100-byte file was kept and its hash certified; now it is made again."""
    from scheimpflug.dataset import verify_dataset

    out = tmp_path / "png"
    _killed_mid_sample(ref, out, "png", "samples/.000000.partial/frames/00003.png")
    os.truncate(out / "samples" / ".000000.partial" / "frames" / "00002.png", 100)
    res, warnings = _make(ref, out)
    assert res.complete and not res.failures, warnings
    assert _hashes(out) == _hashes(ref / "png")  # exact: resume
    assert verify_dataset(out).ok and _leftovers(out) == []


# ------------------------------------------------------------------ a damaged complete dataset


def test_rerunning_make_repairs_missing_and_corrupt_files(ref, tmp_path):
    """Before: a rerun over a complete dataset with damaged files exited 0 and repaired nothing."""
    from scheimpflug.dataset import verify_dataset

    out = tmp_path / "png"
    shutil.copytree(ref / "png", out)
    frame = out / "samples" / "000001" / "frames" / "00003.png"
    data = bytearray(frame.read_bytes())
    data[len(data) // 2] ^= 0x01                                   # same size, other content
    frame.write_bytes(bytes(data))
    (out / "samples" / "000000" / "frames" / "00001.png").unlink()
    os.truncate(out / "samples" / "000000" / "truth" / "00004.npz", 50)
    (out / "samples" / "000001" / "truth" / "mesh.ply").unlink()
    assert not verify_dataset(out).ok
    res, warnings = _make(ref, out)
    assert res.complete and res.frames_rendered == 3, warnings      # only the three damaged frames
    assert any("sample 0 is damaged" in w and "00001.png is missing" in w for w in warnings), warnings
    assert any("sample 1 is damaged" in w and "00003.png: content differs" in w for w in warnings), warnings
    assert _hashes(out) == _hashes(ref / "png")  # exact: resume
    assert verify_dataset(out).ok and _leftovers(out) == []
    (out / "samples" / "000000" / "sample.json").unlink()          # the sample's record itself
    res, warnings = _make(ref, out)
    assert res.complete and res.frames_rendered == 12, warnings
    assert _hashes(out) == _hashes(ref / "png") and verify_dataset(out).ok  # exact: resume
    zarr = tmp_path / "zarr"                                       # a Zarr chunk altered
    shutil.copytree(ref / "zarr", zarr)
    chunk = zarr / "frames.zarr" / "stripe_u" / "c.13.0"
    chunk.write_bytes(chunk.read_bytes()[:-1] + bytes([chunk.read_bytes()[-1] ^ 0xFF]))
    res, warnings = _make(ref, zarr, storage="zarr")
    # exact: resume
    assert res.frames_rendered == 1 and _hashes(zarr) == _hashes(ref / "zarr") and verify_dataset(zarr).ok


# ------------------------------------------------------------------ the regression gate


def test_the_gate_fails_a_detector_that_finds_nothing_and_p99_is_not_capped(ref):
    """Before: an all-NaN detector passed (regression false, missed_rate 1.0); a detector returning
    1e308 had p99 = 99 820 px (the histogram's last edge)."""
    from scheimpflug.dataset import compare_scores, open_dataset, score_dataset

    ds = open_dataset(ref / "png")
    cog = score_dataset(ds, "cog")
    assert compare_scores(cog, cog, 0.02)["regression"] is False
    nothing = score_dataset(ds, f"{ref / 'dets.py'}:nothing")
    gate = compare_scores(nothing, cog, 0.02)
    assert nothing.overall.summary()["missed_rate"] == 1.0
    assert gate["regression"] is True and gate["d_missed_rate"] == pytest.approx(1.0 - cog.overall.summary()
                                                                                 ["missed_rate"])
    assert any(r.startswith("no rms_px") for r in gate["reasons"]), gate["reasons"]
    huge = score_dataset(ds, f"{ref / 'dets.py'}:huge").overall.summary()
    assert huge["p99_px"] == pytest.approx(1e308, rel=1e-9) and huge["outlier_rate"] == 1.0
    inf = score_dataset(ds, f"{ref / 'dets.py'}:infinite").overall
    summary = inf.summary()
    assert summary["infinite_rows"] == summary["matched_rows"] == summary["n_rows"] > 100
    assert summary["outlier_rate"] == 1.0 and inf.quantile(0.99) == np.inf and summary["missed_rate"] == 0.0
    res = subprocess.run([sys.executable, "-m", "scheimpflug", "dataset", "score", str(ref / "png"), "--detector",
                          f"{ref / 'dets.py'}:nothing", "--baseline", "cog", "--max-regression-px", "0.02",
                          "--json", "--quiet"], capture_output=True, text=True,
                         env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert res.returncode == 1, res.stderr
    assert json.loads(res.stdout)["regression"] is True and "missed_rate 1" in res.stderr


# ------------------------------------------------------------------ sizes and bad values


@pytest.mark.parametrize("edit, words", [
    (("samples = 2", "samples = 1_000_000_000_000"), "at most 100,000 samples"),
    (("step_deg = 30.0", "step_deg = 1e-9"), "360,000,000,000 frames per sample"),
])
def test_a_job_too_large_is_refused_with_its_size_at_once(ref, tmp_path, edit, words):
    """Before: planning ran first (10¹² samples: a hang; step 1e-9°: 2.7 GB in 12 s and a lock left)."""
    spec = tmp_path / "big.toml"
    spec.write_text(SPEC.replace(*edit))
    t0 = time.monotonic()
    res = subprocess.run([sys.executable, "-m", "scheimpflug", "dataset", "make", str(spec), "--out",
                          str(tmp_path / "out"), "--quiet"], capture_output=True, text=True, timeout=60,
                         env={**os.environ, "PYTHONPATH": str(ROOT)})
    err = res.stderr.strip().splitlines()
    assert res.returncode == 2 and len(err) == 1 and words in err[0], err
    assert time.monotonic() - t0 < 30 and not (tmp_path / "out").exists()
    from sim.dataset import load_spec, make_dataset

    t0 = time.perf_counter()
    with pytest.raises(DatasetError, match=words):
        make_dataset(load_spec(spec), tmp_path / "out")
    assert time.perf_counter() - t0 < 1.0 and not (tmp_path / "out").exists()


def test_a_zero_rotary_step_is_one_error(tmp_path):
    """Before: ZeroDivisionError (exit 70)."""
    from sim.dataset import load_spec

    (tmp_path / "s.toml").write_text(SPEC.replace("step_deg = 30.0", "step_deg = 0"))
    with pytest.raises(DatasetError, match=r"scenario.step_deg = 0: the rotary step must be > 0"):
        load_spec(tmp_path / "s.toml")


def test_an_spp_beyond_the_memory_budget_is_refused_at_the_spec(tmp_path):
    """Before: accepted at the spec; each sample's renderer then failed (one warning per sample and try)."""
    from sim.dataset import load_spec

    (tmp_path / "s.toml").write_text(SPEC + "spp = 100000000\n")
    with pytest.raises(DatasetError, match=r"scenario.spp = 100000000: .* at most scenario.spp = "):
        load_spec(tmp_path / "s.toml")
    (tmp_path / "ok.toml").write_text(SPEC + "spp = 64\n")
    assert load_spec(tmp_path / "ok.toml").scenario["spp"] == 64


# ------------------------------------------------------------------ failures in the detector and on Dask


def test_a_detector_calling_sys_exit_is_reported_as_its_failure(ref, capsys):
    """Before: a detector raising SystemExit(3) ended `dataset score` with status 3 and no message."""
    from scheimpflug.app.cli import main

    status = main(["dataset", "score", str(ref / "png"), "--detector", f"{ref / 'dets.py'}:exits", "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1, err
    assert "the detector failed on sample 0 frame 0: SystemExit: 3" in err[0]


@pytest.mark.slow
def test_failures_on_two_dask_workers_are_one_line_each(ref, tmp_path, capfd):
    """Before: Dask's 'Compute Failed' traceback blocks (and exit 70 for a worker that died)."""
    from scheimpflug.app.cli import main

    for name, words in (("boom", "the detector failed on sample"), ("dies", "died each time it ran it")):
        status = main(["dataset", "score", str(ref / "png"), "--detector", f"{ref / 'dets.py'}:{name}",
                       "--workers", "2", "--quiet"])
        err = capfd.readouterr().err.strip().splitlines()
        assert status == 2 and len(err) == 1 and words in err[0], err
    # a missing part is a spec error, refused before any sample (before: 4 traceback blocks, then
    # one warning per sample and try)
    spec = tmp_path / "missing.toml"
    spec.write_text(SPEC.replace('part = "cylinder"', 'part = "missing.stl"'))
    status = main(["dataset", "make", str(spec), "--out", str(tmp_path / "out"), "--workers", "2", "--quiet"])
    err = capfd.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1, err
    assert f"part 'missing.stl': no such file ({tmp_path / 'missing.stl'})" in err[0]
    assert not (tmp_path / "out").exists()


# ------------------------------------------------------------------ a full disk


def _enospc(path) -> OSError:
    return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))


def test_a_full_disk_at_the_index_names_the_index_and_leaves_no_lock(ref, tmp_path, monkeypatch):
    """Before: the raw OSError with no path (or the temporary's), and a 0-byte lock left."""
    import pyarrow.parquet as pq

    out = tmp_path / "png"
    shutil.copytree(ref / "png", out)
    real = pq.write_table

    def full(table, where, **kw):
        if Path(where).name.startswith(".index."):
            raise _enospc(where)
        return real(table, where, **kw)

    monkeypatch.setattr(pq, "write_table", full)
    with pytest.raises(DatasetError) as err:
        _make(ref, out)
    msg = str(err.value)
    assert "No space left on device" in msg and f"({out / 'index.parquet'})" in msg, msg
    assert ".tmp" not in msg and not (out / LOCK_NAME).exists() and not list(out.glob(".*.tmp*"))
    monkeypatch.setattr(pq, "write_table", real)
    real_pwrite = os.pwrite
    monkeypatch.setattr(os, "pwrite", lambda fd, data, offset: (_ for _ in ()).throw(_enospc("")))
    with pytest.raises(DatasetError, match=rf"No space left on device \({tmp_path / 'new' / LOCK_NAME}\)"):
        _make(ref, tmp_path / "new")
    assert not (tmp_path / "new").exists()          # no 0-byte lock, no folder
    monkeypatch.setattr(os, "pwrite", real_pwrite)
    assert _make(ref, out)[0].complete and _hashes(out) == _hashes(ref / "png")  # exact: resume


def test_a_full_disk_mid_sample_names_the_real_file_and_resumes_byte_identical(ref, tmp_path, monkeypatch):
    import sim.dataset.sample as sample

    real, calls = sample._write_atomic, []

    def full(path, data):
        calls.append(path)
        if len(calls) == 7:
            raise _enospc(path.with_name(f".{path.name}.tmp1-2"))
        real(path, data)

    monkeypatch.setattr(sample, "_write_atomic", full)
    out = tmp_path / "png"
    res, _ = _make(ref, out, retries=0)
    assert [f["sample"] for f in res.failures] == [0]
    reason = res.failures[0]["error"]
    assert "No space left on device" in reason and "samples/000000/truth/00003.npz" in reason, reason
    assert ".partial" not in reason and ".tmp" not in reason
    monkeypatch.setattr(sample, "_write_atomic", real)
    res, _ = _make(ref, out)
    assert res.complete and _hashes(out) == _hashes(ref / "png") and _leftovers(out) == []  # exact: resume


# ------------------------------------------------------------------ a frame listed twice


def test_verify_refuses_a_frame_listed_twice(ref, tmp_path, capsys):
    """Before: `dataset verify` certified an index listing one frame twice (the same measurement counted
    twice by every score)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from scheimpflug.app.cli import main
    from scheimpflug.dataset import verify_dataset

    out = tmp_path / "png"
    shutil.copytree(ref / "png", out)
    index = pq.read_table(out / "index.parquet")
    rows = index.to_pylist()
    pq.write_table(pa.Table.from_pylist(rows + [dict(rows[0], frame=99)], schema=index.schema),
                   out / "index.parquet")
    rep = verify_dataset(out)
    assert not rep.ok and not (rep.missing or rep.corrupt or rep.extra)
    assert rep.duplicates == [f"sample 0 frame 0 ({rows[0]['file']}) and sample 0 frame 99 ({rows[0]['file']}): "
                              "the same file listed twice"]
    status = main(["dataset", "verify", str(out), "--quiet"])
    assert status == 1 and "duplicate: sample 0 frame 0" in capsys.readouterr().out
    # the same content under two names: frame 1's bytes in frame 2's file, its hash updated everywhere
    pq.write_table(index, out / "index.parquet")
    a, b = rows[1], rows[2]
    shutil.copyfile(out / a["file"], out / b["file"])
    rows[2] = dict(b, sha256=a["sha256"])
    pq.write_table(pa.Table.from_pylist(rows, schema=index.schema), out / "index.parquet")
    files = pq.read_table(out / "files.parquet")
    listed = [dict(f, sha256=a["sha256"], bytes=(out / a["file"]).stat().st_size) if f["path"] == b["file"] else f
              for f in files.to_pylist()]
    pq.write_table(pa.Table.from_pylist(listed, schema=files.schema), out / "files.parquet")
    rep = verify_dataset(out)
    assert rep.corrupt == [] and len(rep.duplicates) == 1
    assert a["file"] in rep.duplicates[0] and b["file"] in rep.duplicates[0] and "same content" in rep.duplicates[0]
