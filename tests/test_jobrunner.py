"""One job runner (issue 25 item 5): `sim.jobfolder` is the resumable-job skeleton of the frame folder,
the dataset and the study — writable check, identity, lock with the stale-owner warning, temporaries,
retries, clean-up on failure — and each of them uses it instead of a copy of its own.

No rendering: a folder, a fake engine and the three job kinds.
"""

from __future__ import annotations

import errno
import json
import re
from pathlib import Path

import pytest

from scheimpflug.errors import DatasetError, RenderError, StudyError
from scheimpflug.io.atomic import finite_json, target_path, target_text
from scheimpflug.io.folder import LOCK_NAME, FolderLock, unwritable_reason
from sim.jobfolder import check_identity, open_job, remove_temporaries, run_with_retries

ROOT = Path(__file__).resolve().parents[1]


def _kinds():
    from sim.dataset.make import DATASET_JOB
    from sim.study.run import STUDY_JOB
    from sim.writer import FRAME_FOLDER

    return DATASET_JOB, STUDY_JOB, FRAME_FOLDER


def test_the_three_jobs_use_the_one_skeleton_and_keep_no_copy():
    """The lock, the probe, the temporaries, the retry loop and NaN → null exist once."""
    sources = {p: (ROOT / p).read_text() for p in ("sim/writer.py", "sim/dataset/make.py", "sim/study/run.py",
                                                    "sim/dataset/sample.py")}
    for path, text in sources.items():
        for copy in ("FolderLock(", "os.access(", "stale_owner", "math.isfinite(obj)", ".glob(\".*.tmp*\")",
                     "for attempt in range(", "write-probe"):
            assert copy not in text, (path, copy)
    for path in ("sim/writer.py", "sim/dataset/make.py", "sim/study/run.py"):
        assert "open_job(" in sources[path] and "remove_temporaries(" in sources[path], path
    probes = [p for p in (ROOT / "scheimpflug").rglob("*.py") if "os.W_OK | os.X_OK" in p.read_text()]
    probes += [p for p in (ROOT / "sim").rglob("*.py") if "os.W_OK | os.X_OK" in p.read_text()]
    assert [p.relative_to(ROOT).as_posix() for p in probes] == ["scheimpflug/io/folder.py"]


@pytest.mark.parametrize("which, identity, changed, message", [
    (0, {"format": 1, "spec": {"a": {"b": 1}}}, {"format": 1, "spec": {"a": {"b": 2}}},
     "holds a dataset made with a different spec ('spec.a.b' differs); choose another --out or delete the folder"),
    (1, {"kind": "sweep", "spec": {}}, {"kind": "tolerance", "spec": {}},
     "holds a study made with the other study command ('kind' differs)"),
    (2, {"seed": 1, "rig": {"sensor": {"rows": 4}}}, {"seed": 1, "rig": {"sensor": {"rows": 8}}},
     "holds a different run ('rig.sensor' differs from this command's); choose another --out or delete "
     "the folder to start over"),
])
def test_identity_messages_of_each_job(tmp_path, which, identity, changed, message):
    kind = _kinds()[which]
    (tmp_path / kind.meta_file).write_text(json.dumps(identity))
    assert check_identity(tmp_path, kind, identity) == identity
    with pytest.raises(kind.error, match=re.escape(message)):
        check_identity(tmp_path, kind, changed)
    (tmp_path / kind.meta_file).unlink()
    (tmp_path / "notes.txt").write_text("mine")
    with pytest.raises(kind.error, match=rf"is not empty and holds no {kind.meta_file} \(found 'notes.txt'\)"):
        check_identity(tmp_path, kind, identity)


def test_inputs_are_compared_over_the_files_both_runs_know(tmp_path):
    kind = _kinds()[0]
    (tmp_path / kind.meta_file).write_text(json.dumps({"inputs": {"rig.toml": "aa"}}))
    assert check_identity(tmp_path, kind, {"inputs": {"rig.toml": "aa", "late.ply": "bb"}}) is not None
    with pytest.raises(DatasetError, match="other input files"):
        check_identity(tmp_path, kind, {"inputs": {"rig.toml": "cc"}})


def test_open_job_creates_locks_warns_about_a_stale_owner_and_cleans_up(tmp_path):
    kind = _kinds()[1]
    out = tmp_path / "job"
    warnings = []
    with open_job(out, kind, {"spec": 1}, warnings.append) as old:
        assert old is None and (out / LOCK_NAME).is_file()
        with pytest.raises(StudyError, match="being written by pid"):      # one writer at a time
            with open_job(out, kind, {"spec": 1}, warnings.append):
                pass
        (out / kind.meta_file).write_text(json.dumps({"spec": 1}))
    assert not (out / LOCK_NAME).exists() and warnings == []
    (out / LOCK_NAME).write_text(json.dumps({"pid": 999999, "host": "gone"}))
    with open_job(out, kind, {"spec": 1}, warnings.append) as old:
        assert old == {"spec": 1}
    assert warnings == ["took over the lock left in " + repr(str(out)) + " by a run that is no longer running "
                        "(pid 999999 on 'gone')"]
    with pytest.raises(StudyError):                        # a failure in a new folder leaves no folder
        with open_job(tmp_path / "new", kind, {"spec": 1}, warnings.append):
            raise StudyError("the job failed")
    assert not (tmp_path / "new").exists()


def test_a_write_that_fails_is_one_error_naming_the_real_file(tmp_path):
    kind = _kinds()[0]
    out = tmp_path / "ds"
    tmp_name = out / "samples" / ".000003.partial" / "frames" / ".00002.png.tmp41-42"
    with pytest.raises(DatasetError) as err:
        with open_job(out, kind, {}, print):
            raise OSError(errno.ENOSPC, "No space left on device", str(tmp_name))
    assert str(err.value) == (f"cannot write into the dataset folder {str(out)!r}: No space left on device "
                              f"({out / 'samples' / '000003' / 'frames' / '00002.png'}); nothing is "
                              "half-written: fix the cause and rerun to resume")
    assert not out.exists()


def test_writable_check_names_the_blocking_path(tmp_path):
    (tmp_path / "file").write_text("")
    probe, reason = unwritable_reason(tmp_path / "file" / "a" / "b")
    assert probe == tmp_path / "file" and reason == "is not a folder"
    assert unwritable_reason(tmp_path / "x" / "y") == (tmp_path, None)
    for error in (DatasetError, StudyError, RenderError):
        with pytest.raises(error, match=rf"output folder .* is not writable: '{tmp_path / 'file'}' is not a folder"):
            with open_job(tmp_path / "file" / "out", next(k for k in _kinds() if k.error is error), None, print):
                pass


def test_temporaries_of_killed_writers_are_removed_and_work_folders_kept(tmp_path):
    (tmp_path / "samples" / ".000001.partial").mkdir(parents=True)
    (tmp_path / "frames.zarr" / "frames").mkdir(parents=True)
    temps = [tmp_path / ".index.abcd1234.tmp.parquet", tmp_path / "samples" / ".x.json.tmp3-4",
             tmp_path / "frames.zarr" / "frames" / "c.0.5e1f.partial"]
    keep = [tmp_path / "index.parquet", tmp_path / "frames.zarr" / "frames" / "c.0.0.0"]
    for p in temps + keep:
        p.write_text("x")
    assert remove_temporaries(tmp_path, ("samples",), deep=("frames.zarr",)) == 3
    assert all(p.exists() for p in keep) and not any(p.exists() for p in temps)
    assert (tmp_path / "samples" / ".000001.partial").is_dir()


class _Item:
    def __init__(self, index):
        self.index = index


class _Engine:
    """The engine's map here: fails item k while ``fails[k]`` > 0."""

    def __init__(self, fails):
        self.fails = dict(fails)

    def map(self, fn, items, key, sizes, base, grand_total):
        for item in items:
            if self.fails.get(item.index, 0) > 0:
                self.fails[item.index] -= 1
                yield item, ValueError(f"item {item.index}  broke\nhere")
            else:
                yield item, fn(item)


def test_retries_record_what_failed_every_time_one_line_per_reason():
    done, warnings = [], []
    failures = run_with_retries(_Engine({1: 1, 2: 5, 3: 5}), lambda item: item.index * 10,
                                [_Item(k) for k in range(4)], noun="sample", key=str, size=lambda i: 1, base=0,
                                grand_total=4, retries=1, warn=warnings.append,
                                on_done=lambda item, res: done.append(res))
    assert sorted(done) == [0, 10]
    assert failures == [{"sample": 2, "error": "ValueError: item 2 broke here"},
                        {"sample": 3, "error": "ValueError: item 3 broke here"}]
    assert sum("will be tried again" in w for w in warnings) == 3
    assert warnings[-2:] == ["sample 2 failed: ValueError: item 2 broke here",
                             "sample 3 failed: ValueError: item 3 broke here"]
    with pytest.raises(StudyError):
        run_with_retries(_Engine({}), lambda item: (_ for _ in ()).throw(StudyError("x")), [_Item(0)], noun="draw",
                         key=str, size=lambda i: 1, base=0, grand_total=1, retries=1, warn=print,
                         on_done=print, fatal=(StudyError,))


def test_target_names_and_finite_json():
    assert target_path("samples/.000003.partial/truth/.00001.npz.tmp5-6") == "samples/000003/truth/00001.npz"
    assert target_path("d/.index.a1b2c3d4.tmp.parquet") == "d/index.parquet"
    assert target_text("cannot write '/d/.000001.partial/x.png' (v1.2)") == "cannot write '/d/000001/x.png' (v1.2)"
    import numpy as np

    assert finite_json({"a": [float("nan"), 1.5, (np.float64("inf"), np.int64(3))]}) == {"a": [None, 1.5, [None, 3]]}


def test_a_lock_that_cannot_be_written_leaves_no_file(tmp_path, monkeypatch):
    import os

    def full(fd, data, offset):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "pwrite", full)
    with pytest.raises(OSError) as err:
        FolderLock(tmp_path).acquire()
    assert err.value.filename == str(tmp_path / LOCK_NAME) and not (tmp_path / LOCK_NAME).exists()
