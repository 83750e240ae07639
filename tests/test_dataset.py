"""`scheimpflug dataset`: specs, seeds, make (PNG and Zarr), the loader, verify, score, bad input.

Small datasets (4 × 4 binned paper sensor, a few frames) made in this process; the
Dask paths are in test_dataset_dask.py.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from scheimpflug.errors import DatasetError

ROOT = Path(__file__).resolve().parents[1]

SPEC = """
[dataset]
seed = 7
samples = 3
[rig]
preset = "paper"
[rig.variation]
"sensor.roll_deg" = [-0.2, 0.2]
[scenario]
kind = "rotary"
part = "sphere"
step_deg = 90.0
frames = 2
binning = 4
[scenario.variation]
material = { choices = ["metal", "cardboard"] }
"""


def _write(path: Path, text: str) -> Path:
    path.write_text(textwrap.dedent(text))
    return path


def _cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "scheimpflug", *map(str, args)], capture_output=True,
                          text=True, cwd=cwd or ROOT,
                          env={**__import__("os").environ, "PYTHONPATH": str(ROOT)})


# ------------------------------------------------------------------ specs and seeds


def test_sample_seed_depends_on_base_seed_and_index_only():
    from sim.dataset.spec import sample_seed

    seeds = [sample_seed(7, k) for k in range(50)]
    assert len(set(seeds)) == 50
    assert sample_seed(7, 3) == seeds[3]
    assert sample_seed(8, 3) != seeds[3]
    expected = int(np.random.SeedSequence((7, 3, 0xDA7A)).generate_state(1, np.uint32)[0])
    assert seeds[3] == expected


def test_draws_are_per_key_and_reproducible(tmp_path):
    from sim.dataset.spec import load_spec, plan_sample

    spec = load_spec(_write(tmp_path / "a.toml", SPEC))
    a = [plan_sample(spec, k) for k in range(3)]
    assert [p.drawn for p in a] == [plan_sample(spec, k).drawn for k in range(3)]
    rolls = [p.drawn["rig.sensor.roll_deg"] for p in a]
    assert all(-0.2 <= r <= 0.2 for r in rolls) and len(set(rolls)) == 3
    assert all(p.rig["sensor"]["roll_deg"] == r for p, r in zip(a, rolls))
    assert all(p.rig["sensor"]["columns"] == 1216 // 4 for p in a)           # binned
    # adding a variation of another key leaves this key's draws unchanged
    spec2 = load_spec(_write(tmp_path / "c.toml", SPEC.replace(
        '"sensor.roll_deg" = [-0.2, 0.2]', '"sensor.roll_deg" = [-0.2, 0.2]\n"sensor.read_noise_e" = [4.0, 8.0]')))
    assert [plan_sample(spec2, k).drawn["rig.sensor.roll_deg"] for k in range(3)] == rolls
    assert a[0].frames == 2 and a[0].seed != a[1].seed


@pytest.mark.parametrize("edit, words", [
    (("[dataset]", "[dataset]\ncolour = 3"), ["unknown key 'colour'", "[dataset]"]),
    (("step_deg = 90.0", "step_degs = 90.0"), ["unknown key 'step_degs'"]),
    (("[-0.2, 0.2]", "[0.2, -0.2]"), ["reversed", "sensor.roll_deg"]),
    (("[-0.2, 0.2]", "[0.1, 0.1]"), ["empty", "sensor.roll_deg"]),
    (('["metal", "cardboard"]', "[]"), ["choices must be a non-empty list"]),
    (('"sensor.roll_deg"', '"sensor.rool_deg"'), ["unknown rig key 'sensor.rool_deg'"]),
    (('kind = "rotary"', 'kind = "spiral"'), ["scenario.kind", "spiral"]),
    (("samples = 3", "samples = 0"), ["dataset.samples"]),
])
def test_bad_spec_is_one_clear_error(tmp_path, edit, words):
    from sim.dataset.spec import load_spec

    path = _write(tmp_path / "bad.toml", SPEC.replace(*edit))
    with pytest.raises(DatasetError) as err:
        load_spec(path)
    assert all(w in str(err.value) for w in words), str(err.value)


# ------------------------------------------------------------------ a small PNG dataset


@pytest.fixture(scope="module")
def png_dataset(tmp_path_factory):
    from sim.dataset import load_spec, make_dataset

    base = tmp_path_factory.mktemp("ds")
    spec = load_spec(_write(base / "spec.toml", SPEC))
    calls = []
    result = make_dataset(spec, base / "png", progress=lambda d, t: calls.append((d, t)))
    return base, result, calls


def test_make_writes_frame_folders_index_ledger_and_card(png_dataset):
    import pyarrow.parquet as pq

    from scheimpflug.io.frames import open_frame_folder

    base, result, calls = png_dataset
    out = base / "png"
    assert result.complete and result.frames == 6 and not result.failures
    assert calls[-1] == (6, 6) and all(d <= t for d, t in calls)
    index = pq.read_table(out / "index.parquet").to_pylist()
    assert [(r["sample"], r["frame"]) for r in index] == [(k, i) for k in range(3) for i in range(2)]
    info = json.loads((out / "dataset.json").read_text())
    assert info["complete"] and info["counts"]["frames"] == 6 and info["spec"]["dataset"]["seed"] == 7
    assert "samples" in (out / "README.md").read_text()
    for k in range(3):   # every sample is a frame folder the pipeline reads
        folder = open_frame_folder(out / "samples" / f"{k:06d}")
        assert len(folder) == 2 and folder.rows == 1936 // 4
        assert [r.angle_deg for r in folder.frames] == [0.0, 90.0]
    row = index[0]
    assert row["angle_deg"] == 0.0 and row["stage_mm"] is None and row["scenario"] == "rotary"
    assert row["materials"] in ("metal", "cardboard") and row["lit_rows"] > 50
    assert -0.2 <= row["rig.sensor.roll_deg"] <= 0.2
    assert not list(out.rglob("*.partial")) and not list(out.rglob(".*.tmp*"))
    pool = list((out / "meshes").glob("*.ply"))      # one sphere, metal or cardboard: ≤ 2 meshes
    assert len(pool) == len({r["materials"] for r in index})
    assert sum(p.stat().st_nlink for p in pool) == len(pool) + 3
    for k in range(3):
        assert any((out / "samples" / f"{k:06d}" / "truth" / "mesh.ply").samefile(p) for p in pool)


def test_loader_reads_frames_truth_and_filters(png_dataset):
    from scheimpflug.dataset import open_dataset
    from sim.writer import read_png

    base, _, _ = png_dataset
    ds = open_dataset(base / "png")
    assert len(ds) == 6 and ds.samples == [0, 1, 2] and ds.storage == "png"
    fr = ds[3]
    assert fr.image.dtype == np.uint16 and fr.image.shape == (1936 // 4, 1216 // 4)
    assert np.array_equal(fr.image, read_png(base / "png" / fr.meta["file"]))  # exact: copy
    with np.load(base / "png" / fr.meta["truth_file"]) as z:
        assert np.array_equal(fr.truth["stripe_u"], z["stripe_u"], equal_nan=True)  # exact: copy
    lit = np.isfinite(fr.truth["stripe_u"])
    assert lit.sum() == fr.meta["lit_rows"]
    assert np.all(np.isfinite(fr.truth["stripe_distance_mm"][lit]))
    assert np.all((fr.truth["stripe_incidence_deg"][lit] >= 0) & (fr.truth["stripe_incidence_deg"][lit] <= 90))
    metal = ds.filter(materials="metal")
    assert all(r["materials"] == "metal" for r in metal.rows())
    assert len(ds.filter(angle_deg=(45.0, 180.0))) == 3
    assert [f.meta["sample"] for f in ds.sample(1)] == [1, 1]
    stack = ds.frames_dask()
    assert stack.shape == (6, 1936 // 4, 1216 // 4)
    assert np.array_equal(np.asarray(stack[3]), fr.image)  # exact: copy
    with pytest.raises(DatasetError, match="unknown index column"):
        ds.filter(colour="red")


def test_truth_distance_and_incidence_match_their_definitions(png_dataset):
    """D from the truth point (reference → rig frame) and the sphere's normal at it."""
    from scheimpflug.dataset import open_dataset
    from scheimpflug.model.hinge import hinge_geometry
    from scheimpflug.model.rig import rig_from_dict
    from sim.stages import rig_from_stage, stage_from_part
    from sim.truth import laser_origin_mm

    base, _, _ = png_dataset
    ds = open_dataset(base / "png")
    fr = ds[1]                                                       # 90°
    manifest = json.loads((ds.sample_folder(fr.meta["sample"]) / "manifest.json").read_text())
    rig = rig_from_dict(manifest["rig"])
    g = hinge_geometry(rig)
    lit = np.isfinite(fr.truth["stripe_u"])
    p_ref = fr.truth["stripe_point_mm"][lit]                         # stage frame, part at θ = 0
    ref_from_part = stage_from_part(rig, 0.0)
    rig_from_ref = rig_from_stage(rig) @ stage_from_part(rig, 90.0) @ np.linalg.inv(ref_from_part)
    p_rig = p_ref @ rig_from_ref[:3, :3].T + rig_from_ref[:3, 3]
    d = (p_rig - g.object_hinge_mm) @ g.propagation_dir
    assert np.allclose(fr.truth["stripe_distance_mm"][lit], d, atol=1e-9)
    # the sphere: Ø25.4 with its lowest point 30 mm above the table, centre on the axis
    centre_ref = ref_from_part[:3, :3] @ [0.0, 0.0, 30.0 + 12.7] + ref_from_part[:3, 3]
    normal = p_ref - centre_ref
    on_ball = np.abs(np.linalg.norm(normal, axis=1) - 12.7) < 0.05
    assert on_ball.sum() > 20
    normal = normal[on_ball] @ rig_from_ref[:3, :3].T
    ray = p_rig[on_ball] - laser_origin_mm(rig)
    cos = np.abs(np.sum(normal * ray, axis=1)) / np.linalg.norm(normal, axis=1) / np.linalg.norm(ray, axis=1)
    # the facet normal of the tessellated sphere deviates from the ball's by < 1.5°
    assert np.allclose(fr.truth["stripe_incidence_deg"][lit][on_ball], np.degrees(np.arccos(cos)), atol=1.5)


def test_rerun_resumes_and_verify_finds_flipped_byte_deleted_frame_and_extra(png_dataset, tmp_path):
    from scheimpflug.dataset import verify_dataset
    from sim.dataset import load_spec, make_dataset

    base, _, _ = png_dataset
    out = tmp_path / "copy"
    shutil.copytree(base / "png", out)
    again = make_dataset(load_spec(base / "spec.toml"), out)
    assert again.samples_made == 0 and again.frames_rendered == 0 and again.complete
    assert verify_dataset(out).ok
    frame = out / "samples" / "000001" / "frames" / "00001.png"
    data = bytearray(frame.read_bytes())
    data[len(data) // 2] ^= 0x01
    frame.write_bytes(bytes(data))
    (out / "samples" / "000002" / "frames" / "00000.png").unlink()
    (out / "samples" / "000000" / "stray.txt").write_text("x")
    rep = verify_dataset(out)
    assert rep.corrupt == ["samples/000001/frames/00001.png"]
    assert rep.missing == ["samples/000002/frames/00000.png"]
    assert rep.extra == ["samples/000000/stray.txt"]
    res = _cli("dataset", "verify", out, "--json")
    assert res.returncode == 1
    got = json.loads(res.stdout)
    assert (got["frames"], got["missing"], got["corrupt"], got["extra"]) == (6, 1, 1, 1)


# ------------------------------------------------------------------ Zarr


def test_zarr_holds_the_same_frames_and_truth_lazily(png_dataset):
    import dask.array as da
    import zarr

    from scheimpflug.dataset import open_dataset, verify_dataset
    from sim.dataset import load_spec, make_dataset

    base, _, _ = png_dataset
    out = base / "zarr"
    make_dataset(load_spec(base / "spec.toml"), out, storage="zarr")
    png, zds = open_dataset(base / "png"), open_dataset(out)
    assert zds.storage == "zarr" and len(zds) == 6
    store = zarr.open_group(str(out / "frames.zarr"), mode="r")
    arr = store["frames"]
    assert arr.shape == (6, 1936 // 4, 1216 // 4) and arr.chunks == (1, 1936 // 4, 1216 // 4)
    blosc = arr.metadata.codecs[-1]
    assert (blosc.cname.value, blosc.clevel, blosc.shuffle.value) == ("zstd", 1, "bitshuffle")
    assert blosc.blocksize == 1 << 21
    for a, b in zip(png, zds):
        assert np.array_equal(a.image, b.image)  # exact: copy
        for key in a.truth:
            assert np.array_equal(a.truth[key], b.truth[key], equal_nan=True), key  # exact: copy
    lazy = zds.frames_dask()
    assert isinstance(lazy, da.Array) and lazy.chunks[0] == (1,) * 6
    assert np.array_equal(lazy[4].compute(), png[4].image)  # exact: copy
    xds = zds.filter(sample=2).to_xarray()
    assert xds["frames"].dims == ("frame", "row", "column") and xds.sizes["frame"] == 2
    assert np.array_equal(xds["stripe_u"].values, np.stack([f.truth["stripe_u"] for f in png.sample(2)]),  # exact: copy
                          equal_nan=True)
    # chunks written by the dataset's encoder are byte for byte what Zarr itself writes
    ref = zarr.open_group(str(base / "ref.zarr"), mode="w")
    ref.create_array("frames", shape=arr.shape, chunks=arr.chunks, dtype=arr.dtype,
                     compressors=arr.metadata.codecs[-1], chunk_key_encoding={"name": "default", "separator": "."})
    ref["frames"][4] = png[4].image
    # exact: resume
    assert (base / "ref.zarr/frames/c.4.0.0").read_bytes() == (out / "frames.zarr/frames/c.4.0.0").read_bytes()
    assert verify_dataset(out).ok


# ------------------------------------------------------------------ scoring


def test_score_cog_agrees_with_statistics_computed_here(png_dataset):
    from scheimpflug.dataset import open_dataset, score_dataset
    from scheimpflug.stripe import extract_stripes

    base, _, _ = png_dataset
    ds = open_dataset(base / "png")
    rep = score_dataset(ds, "cog").to_json()
    errs, missed, truth_rows, false, empty = [], 0, 0, 0, 0
    for fr in ds:
        prof = extract_stripes(fr.image, "cog", saturation_dn=4095.0)
        found = np.full(fr.image.shape[0], np.nan)
        found[prof.rows] = prof.u
        t = fr.truth["stripe_u"]
        has_t, has_d = np.isfinite(t), np.isfinite(found)
        errs.append(found[has_t & has_d] - t[has_t & has_d])
        missed += int((has_t & ~has_d).sum())
        truth_rows += int(has_t.sum())
        false += int((~has_t & has_d).sum())
        empty += int((~has_t).sum())
    e = np.concatenate(errs)
    inl = np.abs(e) <= 1.0
    assert rep["n_rows"] == truth_rows
    assert rep["bias_px"] == pytest.approx(e[inl].mean(), abs=1e-12)
    assert rep["rms_px"] == pytest.approx(np.sqrt(np.mean(e[inl] ** 2)), abs=1e-12)
    assert rep["outlier_rate"] == pytest.approx((~inl).mean(), abs=1e-12)
    assert rep["missed_rate"] == pytest.approx(missed / truth_rows, abs=1e-12)
    assert rep["false_rate"] == pytest.approx(false / empty, abs=1e-12)
    # p99 from a 0.0005 px histogram: within a bin of numpy's order statistic
    assert abs(rep["p99_px"] - np.quantile(np.abs(e), 0.99, method="inverted_cdf")) <= 0.0006
    groups = rep["by_material"]
    assert set(groups) <= {"metal", "cardboard"}
    assert sum(g["n_rows"] for g in groups.values()) == truth_rows


def test_biased_detector_bias_and_regression_exit(png_dataset, tmp_path):
    base, _, _ = png_dataset
    det = _write(tmp_path / "mydet.py", """
        import numpy as np
        from scheimpflug.stripe import extract_stripes

        def biased(frame):
            prof = extract_stripes(frame, "cog", saturation_dn=4095.0)
            out = np.full(frame.shape[0], np.nan)
            out[prof.rows] = prof.u + 0.3
            return out
        """)
    out = base / "png"
    res = _cli("dataset", "score", out, "--detector", f"{det}:biased", "--baseline", "cog",
               "--max-regression-px", "0.1", "--where", "materials=cardboard", "--json",
               "--plot", tmp_path / "err.png")
    assert res.returncode == 1, res.stderr
    got = json.loads(res.stdout)
    assert list(got["by_material"]) == ["cardboard"]
    assert got["bias_px"] - got["baseline"]["bias_px"] == pytest.approx(0.3, abs=1e-3)
    assert got["bias_px"] == pytest.approx(0.3, abs=0.01)      # cog on a matte sphere is unbiased
    assert got["regression"] is True and got["d_abs_bias_px"] > 0.1
    assert (tmp_path / "err.png").stat().st_size > 10_000
    res = _cli("dataset", "score", out, "--detector", "cog", "--baseline", "cog",
               "--max-regression-px", "0.1", "--json")
    assert res.returncode == 0 and json.loads(res.stdout)["regression"] is False
    res = _cli("dataset", "score", out, "--detector", "nosuchmodule:fn")
    assert res.returncode == 2 and "cannot import 'nosuchmodule'" in res.stderr


# ------------------------------------------------------------------ bad input: one error, nothing written


def test_bad_input_one_error_and_nothing_half_written(png_dataset, tmp_path):
    base, _, _ = png_dataset
    spec = base / "spec.toml"
    bad = _write(tmp_path / "bad.toml", SPEC.replace('"sensor.roll_deg" = [-0.2, 0.2]',
                                                     '"sensor.roll_deg" = [0.2, -0.2]'))
    cases = [
        (("dataset", "make", bad, "--out", tmp_path / "o1"), "reversed", tmp_path / "o1"),
        (("dataset", "make", _write(tmp_path / "k.toml", SPEC + "[scenario.colour]\n"), "--out",
          tmp_path / "o2"), "unknown key", tmp_path / "o2"),
        (("dataset", "make", spec, "--out", tmp_path / "o3", "--scheduler", "tcp://127.0.0.1:9",
          "--connect-timeout", "1"), "cannot reach the Dask scheduler", tmp_path / "o3"),
    ]
    blocker = tmp_path / "a-file"
    blocker.write_text("x")
    cases.append((("dataset", "make", spec, "--out", blocker / "sub"), "is not writable", blocker / "sub"))
    for args, words, out in cases:
        res = _cli(*args)
        assert res.returncode == 2, (args, res.stderr)
        last = res.stderr.strip().splitlines()[-1]
        assert words in last and last.startswith("scheimpflug dataset: error:"), last
        assert not out.exists()
    # a folder made by a different spec is refused and left as it was
    other = _write(tmp_path / "other.toml", SPEC.replace("step_deg = 90.0", "step_deg = 45.0"))
    before = {p: p.stat().st_mtime_ns for p in (base / "png").rglob("*")}
    res = _cli("dataset", "make", other, "--out", base / "png")
    assert res.returncode == 2 and "different spec ('spec.scenario.step_deg' differs)" in res.stderr
    assert {p: p.stat().st_mtime_ns for p in (base / "png").rglob("*")} == before


@pytest.mark.parametrize("path", sorted((ROOT / "datasets" / "examples").glob("*.toml")), ids=lambda p: p.stem)
def test_example_specs_parse_and_plan(path):
    from sim.dataset.spec import load_spec, plan_sample

    spec = load_spec(path)
    plans = [plan_sample(spec, k) for k in range(min(spec.samples, 20))]
    assert all(p.frames >= 1 for p in plans)
    for p in plans:
        if p.part.endswith((".toml", ".stl", ".ply", ".obj")):
            assert Path(p.options["part"]).is_file(), p.options["part"]


def test_a_second_make_into_the_same_folder_is_refused(tmp_path):
    """One writer per dataset folder (issue 12's lock, reused): a held lock refuses a second make."""
    from scheimpflug.io.folder import FolderLock
    from sim.dataset.make import make_dataset
    from sim.dataset.spec import load_spec

    spec_file = _write(tmp_path / "spec.toml", SPEC)
    out = tmp_path / "ds"
    out.mkdir()
    with FolderLock(out):
        with pytest.raises(DatasetError, match="being written by"):
            make_dataset(load_spec(spec_file), out)
    assert sorted(p.name for p in out.iterdir()) == []


def test_next_sample_of_the_same_part_reuses_its_mesh_with_the_same_bytes(tmp_path):
    """A worker's next sample of the same part reuses the assembly and links the pooled truth mesh;
    that mesh holds exactly the bytes a fresh build of the part writes."""
    from sim.dataset.make import make_dataset
    from sim.dataset.spec import load_spec
    from sim.scenarios import load_assembly, reuse_assemblies, rotary_scenario

    cache: dict = {}
    with reuse_assemblies(cache):
        a, b, c = load_assembly("sphere"), load_assembly("sphere", seed=5), load_assembly("plate")
    assert a is b and c is not a and load_assembly("sphere") is not a     # reuse ends with the block
    spec = SPEC.split("[scenario.variation]")[0].replace("samples = 3", "samples = 2")
    spec = spec.replace("[rig.variation]\n\"sensor.roll_deg\" = [-0.2, 0.2]\n", "").replace("frames = 2", "frames = 1")
    out = tmp_path / "ds"
    assert make_dataset(load_spec(_write(tmp_path / "spec.toml", spec)), out).complete
    meshes = [out / "samples" / f"{k:06d}" / "truth" / "mesh.ply" for k in range(2)]
    pool = list((out / "meshes").glob("*.ply"))
    assert len(pool) == 1 and all(m.samefile(pool[0]) for m in meshes)
    from scheimpflug.model.rig import load_preset

    rig = load_preset("paper")
    fresh = rotary_scenario(rig, part="sphere", step_deg=90.0, frames=1, truth_pixels_every=0)
    fresh.assembly.transformed(fresh.mesh_ref_from_part).to_ply(tmp_path / "fresh.ply")
    assert (tmp_path / "fresh.ply").read_bytes() == meshes[1].read_bytes()  # exact: same run
