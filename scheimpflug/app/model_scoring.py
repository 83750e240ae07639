"""A surface model against the true mesh: two-sided distances and volumes, whole and per object.

Shared by ``evaluate --model`` and the demo.  Each body of the model is
assigned to the true object (``object_id`` of ``truth/mesh.ply``, or the
connected body) that most of its surface samples lie nearest to; an object's
model volume is the sum of its bodies' volumes.
"""

from __future__ import annotations

import numpy as np

__all__ = ["model_lines", "object_volumes", "score_model", "score_model_mesh"]


def object_volumes(truth_pm, labels: np.ndarray, model_vertices, model_faces, model_body,
                   two_sided) -> dict:
    """Per true object: true volume, model volume (its bodies) and the error [mm³]."""
    from scheimpflug.scoring import is_closed_mesh
    from scheimpflug.volumetry import mesh_volume_mm3

    body_of_sample = model_body[two_sided.model_face]
    object_of_sample = labels[two_sided.truth_face]
    out = {}
    for obj in np.unique(labels):
        faces = truth_pm.faces[labels == obj]
        out[str(int(obj))] = {"true_volume_mm3": mesh_volume_mm3(truth_pm.vertices, faces) if is_closed_mesh(faces)
                              else None, "model_volume_mm3": 0.0, "bodies": []}
    for b in np.unique(model_body):
        votes = object_of_sample[body_of_sample == b]
        if votes.size == 0:
            continue
        obj = out[str(int(np.bincount(votes).argmax()))]
        obj["bodies"].append(int(b))
        obj["model_volume_mm3"] += mesh_volume_mm3(model_vertices, model_faces[model_body == b])
    for obj in out.values():
        t = obj["true_volume_mm3"]
        obj["volume_error_mm3"] = None if t is None else obj["model_volume_mm3"] - t
        obj["volume_error_rel"] = None if not t else obj["volume_error_mm3"] / t
    return out


def score_model_mesh(truth_pm, labels, vertices, faces, body, fill, *, samples=200_000, seed=0,
                     coverage_mm=0.1):
    """Two-sided scores of a model given as arrays; returns (JSON-ready dict, TwoSidedDistance)."""
    from scheimpflug.scoring import PointToMesh, is_closed_mesh, two_sided_distance
    from scheimpflug.volumetry import mesh_volume_mm3

    model_pm = PointToMesh(vertices, faces, signed=False)   # truth → model distances are unsigned
    ts = two_sided_distance(truth_pm, model_pm, n_samples=samples, seed=seed, coverage_mm=coverage_mm)
    true_volume = mesh_volume_mm3(truth_pm.vertices, truth_pm.faces) if truth_pm.closed else None
    model_volume = mesh_volume_mm3(vertices, faces)
    out = {"coverage": ts.coverage, "hausdorff_mm": ts.hausdorff_mm, "mean_mm": ts.mean_mm,
           "volume_mm3": model_volume, "true_volume_mm3": true_volume,
           "volume_error_mm3": None if true_volume is None else model_volume - true_volume,
           "model_watertight": bool(is_closed_mesh(faces)),   # bodies share no vertex: each is closed
           "two_sided": ts.to_dict(), "objects": object_volumes(truth_pm, labels, vertices, faces, body, ts)}
    if fill is not None:
        measured = fill[ts.model_face] == 0
        out["model_to_truth_measured_mean_mm"] = (float(np.mean(np.abs(ts.model_to_truth_mm[measured])))
                                                  if measured.any() else None)
    return out, ts


def score_model(truth_pm, labels, model_path, **kw) -> dict:
    """``evaluate --model``: read the model file and score it (:func:`score_model_mesh`)."""
    from scheimpflug.io.ply import read_triangle_mesh

    m = read_triangle_mesh(model_path)
    from scheimpflug.scoring import body_labels

    body = m.face_properties.get("body")
    body = body_labels(m.faces) if body is None else np.asarray(body, np.int64)
    fill = m.face_properties.get("fill")
    out, _ = score_model_mesh(truth_pm, labels, m.vertices, m.faces, body, fill, **kw)
    return {"model": str(model_path), **out}


def model_lines(out: dict) -> list[str]:
    ts = out["two_sided"]
    lines = [f"model {out.get('model', '')}: coverage {100 * out['coverage']:.2f} % of the true surface within "
             f"{ts['coverage_mm']:g} mm; symmetric mean {out['mean_mm']:.4f} mm, "
             f"Hausdorff {out['hausdorff_mm']:.4f} mm",
             f"  truth → model: mean {ts['truth_to_model']['mean_abs_mm']:.4f} mm, p95 "
             f"{ts['truth_to_model']['p95_mm']:.4f} mm; model → truth: mean {ts['model_to_truth']['mean_abs_mm']:.4f}"
             f" mm, p95 {ts['model_to_truth']['p95_mm']:.4f} mm"]
    if out["volume_error_mm3"] is not None:
        rel = 100 * out["volume_error_mm3"] / out["true_volume_mm3"]
        lines.append(f"  volume {out['volume_mm3']:.6g} mm³ vs true {out['true_volume_mm3']:.6g} mm³: error "
                     f"{out['volume_error_mm3']:+.6g} mm³ ({rel:+.3f} %)")
    for k, o in out["objects"].items():
        if o["volume_error_mm3"] is not None and len(out["objects"]) > 1:
            lines.append(f"  object {k}: bodies {o['bodies']}, volume {o['model_volume_mm3']:.6g} vs "
                         f"{o['true_volume_mm3']:.6g} mm³ ({100 * o['volume_error_rel']:+.2f} %)")
    return lines
