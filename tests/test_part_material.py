"""The rotary part's material tag (issue 36: the part's material in the twin).

``render rotary --part-material TAG`` (:func:`sim.scenarios.rotary_scenario`'s ``part_material``),
the twin's part material and medium (``twin.json``'s ``part_material``, :func:`sim.twin.load_twin`),
and the scan identification's unknowns of a translucent part (:func:`sim.identify.scan.default_unknowns`,
:func:`sim.identify.scan.material_settings`).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from scheimpflug.app.cli import EXIT_ERROR, main
from scheimpflug.errors import MeshError, StudyError


def _box_stl(path: Path, size_mm: float = 40.0) -> Path:
    import trimesh

    box = trimesh.creation.box([size_mm, size_mm, size_mm])
    box.apply_translation([0.0, 0.0, size_mm / 2.0])         # standing on the table, on the axis
    box.export(path)
    return path


@pytest.fixture
def paper(paper_rig):
    return paper_rig


def test_rotary_part_material_sets_every_parts_tag(tmp_path, paper):
    from sim.scenarios import rotary_scenario

    stl = _box_stl(tmp_path / "box.stl")
    mesh = rotary_scenario(paper, part=str(stl), frames=1, part_material="white-plastic")
    assert [p.material for p in mesh.assembly.parts] == ["white-plastic"]
    assert mesh.params["part_material"] == "white-plastic"
    assert [p["material"] for p in mesh.params["parts"]] == ["white-plastic"]
    assert [p.material for p in rotary_scenario(paper, part=str(stl), frames=1).assembly.parts] == ["metal"]
    assert "part_material" not in rotary_scenario(paper, part=str(stl), frames=1).params
    preset = rotary_scenario(paper, part="box", frames=1, part_material="marble")          # a preset's parts
    assert [p.material for p in preset.assembly.parts] == ["marble"]


@pytest.mark.parametrize("part, tag, words", [
    ("box", "plaster", "unknown material tag"),
    ("box", "", "unknown material tag"),
    ("scene", "paper", "is a scene file"),
])
def test_bad_part_material_is_one_mesh_error(tmp_path, paper, part, tag, words):
    from sim.scenarios import rotary_scenario

    path = _box_stl(tmp_path / "box.stl") if part == "box" else tmp_path / "scene.toml"
    with pytest.raises(MeshError, match=words) as err:
        rotary_scenario(paper, part=str(path), frames=1, part_material=tag)
    if part == "box":
        assert "white-plastic" in str(err.value) and "metal" in str(err.value)     # the known tags listed


def test_render_refuses_an_unknown_tag_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["render", "rotary", "--preset", "paper", "--binning", "8", "--part", "cylinder", "--frames", "1",
                 "--part-material", "granite", "--out", str(out), "--quiet"]) == EXIT_ERROR
    err = capsys.readouterr().err
    assert "'granite'" in err and "unknown material tag" in err and len(err.strip().splitlines()) == 1
    assert not out.exists() or not any(out.rglob("*.png"))
    assert main(["render", "calibration", "--preset", "paper", "--binning", "8", "--part-material", "paper",
                 "--out", str(out), "--quiet"]) == EXIT_ERROR
    assert "--part-material applies to the rotary scenario only" in capsys.readouterr().err


def _light_beyond(img: np.ndarray, core_px: int) -> tuple[float, int]:
    """Per line across the stripe (a row of ``img``): the light beyond ±core_px of its peak (out to 12 core_px)
    over the light within, the line's median removed, summed over the lines whose peak is well above it."""
    img = img.astype(np.float64)
    img = img - np.median(img, axis=1, keepdims=True)
    peak = img.max(axis=1)
    lines = np.nonzero(peak > 0.3 * np.max(peak))[0]
    cols = np.arange(img.shape[1])
    far = near = 0.0
    for r in lines:
        d = np.abs(cols - int(np.argmax(img[r])))
        q = np.clip(img[r], 0.0, None)
        far += float(q[(d > core_px) & (d <= 12 * core_px)].sum())
        near += float(q[d <= core_px].sum())
    return far / (near + far), len(lines)


@pytest.mark.render
def test_translucent_part_glows_beyond_the_metal_ones_stripe(tmp_path):
    """A box part rendered metal and white-plastic (subsurface on), one 8 × 8-binned frame each: light enters
    the plastic and leaves it millimetres away (white-plastic's σ_s' = 2.5 /mm, σ_a = 0.003 /mm: a transport
    mean free path of 0.4 mm and a diffusion length 1/√(3 σ_a (σ_a + σ_s')) ≈ 6.7 mm, both beyond a binned
    pixel's ≈ 0.2 mm footprint), so far more of the stripe's light lies beyond its core than on the metal
    part, whose wings are the sheet's own Gaussian falloff."""
    from scheimpflug.io.frames import open_frame_folder

    stl = _box_stl(tmp_path / "box.stl")
    got = {}
    for tag in ("metal", "white-plastic"):
        out = tmp_path / tag
        assert main(["render", "rotary", "--preset", "paper", "--binning", "8", "--part", str(stl), "--frames", "1",
                     "--part-material", tag, "--subsurface", "--truth-pixels", "none", "--out", str(out),
                     "--quiet"]) == 0
        man = json.loads((out / "manifest.json").read_text())
        assert man["scenario_params"]["part_material"] == tag
        folder = open_frame_folder(out)
        img = folder.read(0)
        got[tag] = _light_beyond(img.T if folder.stripe_along == "rows" else img, 2)   # lines across it
    (metal, n_metal), (plastic, n_plastic) = got["metal"], got["white-plastic"]
    assert n_metal > 10 and n_plastic > 10
    assert metal < 0.1 and plastic > 4.0 * metal, got          # measured: 0.032 and 0.36


# ------------------------------------------------------------------ the twin and the identification


def test_default_unknowns_of_a_translucent_and_a_metal_part(paper):
    from scheimpflug.model.rig import rig_to_dict
    from sim.identify.scan import DEFAULT_PART_MATERIAL, PART_MEDIUM_PRIORS, default_unknowns

    tables = rig_to_dict(paper)
    plastic = default_unknowns(tables)
    assert DEFAULT_PART_MATERIAL == "white-plastic"
    assert plastic["material.part_sigma_s_per_mm"] == {"range": [0.5, 50.0], "prior": "log-uniform"}
    assert plastic["material.part_diffusion_mm"] == {"range": [0.3, 10.0], "prior": "log-uniform"}
    assert "material.metal_alpha" not in plastic and set(PART_MEDIUM_PRIORS) == {
        "part_sigma_s_per_mm", "part_diffusion_mm"}
    metal = default_unknowns(tables, "metal")
    assert "material.metal_alpha" in metal and not any(k.startswith("material.part_") for k in metal)
    assert set(plastic) - set(metal) == {"material.part_sigma_s_per_mm", "material.part_diffusion_mm"}


@pytest.mark.parametrize("sigma_s, sigma_a", [(0.5, 1e-4), (2.5, 0.003), (50.0, 0.3), (10.0, 1.0)])
def test_absorption_from_the_diffusion_length(sigma_s, sigma_a):
    """σ_a from σ_s' and the diffusion length 1/√(3 σ_a (σ_a + σ_s')) (the diffusion approximation's σ_eff)."""
    from sim.identify.scan import absorption_per_mm

    diffusion_mm = 1.0 / np.sqrt(3.0 * sigma_a * (sigma_a + sigma_s))
    assert absorption_per_mm(sigma_s, diffusion_mm) == pytest.approx(sigma_a, rel=1e-9)


def test_material_settings_replace_only_the_parts_medium():
    from sim.identify.scan import material_settings
    from sim.materials import TRANSLUCENT, MaterialSettings

    kw = material_settings({"cardboard_albedo": 0.4, "part_sigma_s_per_mm": 7.0, "part_sigma_a_per_mm": 0.02},
                           "white-plastic")
    by_length = material_settings({"part_sigma_s_per_mm": 7.0, "part_diffusion_mm": 1.0 / np.sqrt(3 * 0.02 * 7.02)},
                                  "white-plastic")
    assert by_length["translucent"]["white-plastic"].sigma_a_per_mm == pytest.approx(0.02, rel=1e-9)
    s = MaterialSettings(**kw)
    m = s.medium("white-plastic")
    assert (m.sigma_s_per_mm, m.sigma_a_per_mm) == (7.0, 0.02)   # exact: copy
    assert (m.eta, m.alpha, m.g) == (TRANSLUCENT["white-plastic"].eta, TRANSLUCENT["white-plastic"].alpha, 0.0)
    assert s.cardboard_albedo == 0.4 and s.medium("cardboard") == TRANSLUCENT["cardboard"]
    assert material_settings({"metal_alpha": 0.3}, "metal") == {"metal_alpha": 0.3}
    with pytest.raises(ValueError, match="needs a translucent part tag"):
        material_settings({"part_sigma_s_per_mm": 7.0}, "metal")
    with pytest.raises(ValueError, match="give one"):
        material_settings({"part_sigma_a_per_mm": 0.1, "part_diffusion_mm": 2.0}, "white-plastic")


def test_twin_json_part_material_reaches_the_renderer(tmp_path):
    """``twin.json``'s part material and identified medium → :class:`sim.twin.TwinFiles` → MaterialSettings."""
    from sim.materials import MaterialSettings
    from sim.twin import load_twin

    medium = {"sigma_s_per_mm": 6.5, "sigma_a_per_mm": 0.012, "g": 0.0, "eta": 1.49, "alpha": 0.1,
              "albedo": 0.83, "source": "identified"}
    for name in ("rig.toml", "part.ply", "identify/identified.toml"):
        (tmp_path / name).parent.mkdir(exist_ok=True)
        (tmp_path / name).write_text("")
    meta = {"format": "scheimpflug-twin/1", "complete": True, "angles_deg": [0.0],
            "files": {"rig": "rig.toml", "part": "part.ply", "housing": None,
                      "identified_rig": "identify/identified.toml"},
            "identified": {"material.cardboard_albedo": {"value": 0.3},
                           "material.part_sigma_s_per_mm": {"value": 6.5},
                           "material.part_diffusion_mm": {"value": 2.0}},
            "part_material": {"tag": "white-plastic", "medium": medium}}
    (tmp_path / "twin.json").write_text(json.dumps(meta))
    twin = load_twin(tmp_path)
    assert twin.part_material == "white-plastic"
    s = MaterialSettings(**twin.materials)
    assert s.cardboard_albedo == 0.3   # exact: copy
    m = s.medium("white-plastic")
    assert (m.sigma_s_per_mm, m.sigma_a_per_mm) == (6.5, 0.012)   # exact: copy
    # a twin built before part_material: the mesh's own tag (metal), its identified roughness
    del meta["part_material"]
    meta["identified"] = {"material.metal_alpha": {"value": 0.4}}
    (tmp_path / "twin.json").write_text(json.dumps(meta))
    old = load_twin(tmp_path)
    assert old.part_material is None and old.materials == {"metal_alpha": 0.4}


def test_identify_scan_refuses_a_part_tag_the_table_has(tmp_path, paper):
    """The part's identified medium replaces its tag's: a tag the table (cardboard) shares is refused, as is an
    unknown tag, before anything is written."""
    import cv2

    from scheimpflug.model.rig import rig_to_toml
    from sim.identify.scan import identify_scan

    twin = tmp_path / "twin"
    twin.mkdir()
    (twin / "rig.toml").write_text(rig_to_toml(paper.replace(stage={"table_material": "cardboard"})))
    (twin / "part.ply").write_text("ply\n")
    real = tmp_path / "real"
    (real / "frames").mkdir(parents=True)
    frames = []
    for i in range(4):
        cv2.imwrite(str(real / "frames" / f"{i:05d}.png"), np.zeros((paper.sensor.rows, paper.sensor.columns),
                                                                      np.uint8))
        frames.append({"file": f"frames/{i:05d}.png", "angle_deg": 90.0 * i})
    (real / "manifest.json").write_text(json.dumps({"format": "scheimpflug-frames/1", "complete": True,
                                                    "frames": frames, "stripe_along": "columns"}))
    for tag, words in (("cardboard", "the table or the housing is of that tag"), ("plaster", "unknown material")):
        with pytest.raises(StudyError, match=words):
            identify_scan(twin, real, {"part": (0.0, 100.0)}, fit_frames=[0, 2], held_frames=[1],
                          out=tmp_path / "out", part_material=tag)
        assert not (tmp_path / "out").exists()


def test_a_translucent_part_turns_the_twins_subsurface_on(paper):
    """The identification's rig tables (whence the identified rig) get ``[twin] subsurface = true`` for a
    translucent part, and stay as they are for a metal one."""
    from scheimpflug.model.rig import rig_to_dict
    from sim.identify.scan import _part_tables

    tables = rig_to_dict(paper.replace(twin={"subsurface": False}))
    assert _part_tables(tables, None, "white-plastic")["twin"]["subsurface"] is True
    assert _part_tables(tables, None, "metal") == tables
