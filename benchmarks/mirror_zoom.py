"""The mirror test inside the zoom test: both looks mirror-averaged, then the kinematic fit.

    python benchmarks/mirror_zoom.py [CHECKPOINT] [--out FILE] [--threads 2]

``armpose predict --mirror --zoom --fit`` runs every forward pass of the zoom test (the first
pass and the second look) on the image and its mirror (:mod:`armpose.mirror_test`), while the
``evaluate`` stage scores the zoom test and the fit on single passes only. This script asks
what the mirror adds there: the zoom test plus the fit, with single and with mirror-averaged
passes, on the held-out training frames of ``benchmarks/ray_bone_fit.py`` (outside both
transfer sets, 200 per robot type), to choose on, and on the test split. Per family (UR, KUKA,
Panda): joint and base medians (cm), type and mask accuracy, from
:func:`armpose.evaluate.metrics_by_group`. ``fit`` uses the checkpoint's stored per-type
settings (``extra.fit_sigmas``: measured after stage 2, on single passes unless its
``fit_sigmas_on_mirror`` was set); with mirror-averaged passes, ``fit_sigmas_measured_on_mirror``
also fits the same estimates with settings measured on mirror-averaged passes
(:func:`armpose.fit_sigmas.measure_fit_sigmas`, the held-out frames of stage 2, as
``transfer_stage2.fit_sigmas_on_mirror: true`` stores them). Written to ``--out`` as JSON
(atomically).
"""
from __future__ import annotations

import json

from armpose.config import load_params
from armpose.data import split_indices
from armpose.evaluate import fitted, metrics_by_group, pixel_scale_of, predict_split
from armpose.fit_sigmas import checkpoint_fit_sigmas, measure_fit_sigmas
from armpose.io import atomic_write_json
from armpose.kinematic_fit import FitSettings
from armpose.labels.dataset import load_dataset
from armpose.train import training_rows
from armpose.zoom_test import settings_from_config

from checkpoint_cli import load_checkpoint_from_cli
from ray_bone_fit import held_out_rows

KEYS = ("mask_accuracy", "type_accuracy", "joint_median_cm", "base_median_cm")


def score(model, data_dir, rows, settings: dict, sigma_sets: dict, base: dict, on_mirror: bool) -> dict:
    """Per family :data:`KEYS` of the zoom test and of the fit after it, for ``model`` on ``rows``,
    on single passes or (``on_mirror``) on the mirror test's (``predict_split(zoom_on_mirror=True)``):
    ``"zoom"``, and one entry per named fit settings in ``sigma_sets`` (the zoom test run once)."""
    pred, truth = predict_split(model, data_dir, rows=rows, mirror=on_mirror, zoom=True, zoom_settings=settings,
                                zoom_on_mirror=on_mirror)
    types, scale = list(base["robot_types"]), pixel_scale_of(base, truth)
    looks = {"zoom": pred["zoom"], **{name: fitted(pred["zoom"], types, FitSettings(), sigmas)
                                      for name, sigmas in sigma_sets.items()}}
    out = {}
    for name, seen in looks.items():
        m = metrics_by_group(seen, truth, types, scale)
        out[name] = {fam: {k: m["by_family"][fam][k] for k in KEYS} for fam in m["by_family"]}
    return out


def main() -> None:
    args, root, model, config = load_checkpoint_from_cli(__doc__)
    data_dir, params = root / "data" / "labels", load_params(root / "params.yaml")
    arrays, _ = load_dataset(data_dir)
    splits = {"held_out": held_out_rows(data_dir, params), "test": split_indices(arrays, "test")}
    settings, stored = settings_from_config(config), checkpoint_fit_sigmas(root / args.checkpoint)
    used = training_rows(arrays, params["transfer_stage2"], params["base"])
    _, on_mirror_sigmas = measure_fit_sigmas(model, config, data_dir, used, int(params["base"]["seed"]), on_mirror=True)
    result = {"checkpoint": str(args.checkpoint), "zoom_settings": settings,
              "fit_sigmas": {"stored": stored, "measured_on_mirror": on_mirror_sigmas}}
    for split, rows in splits.items():
        result[split] = {"frames": int(len(rows)),
                         "single": score(model, data_dir, rows, settings, {"fit": stored}, params["base"], False),
                         "mirror": score(model, data_dir, rows, settings,
                                         {"fit": stored, "fit_sigmas_measured_on_mirror": on_mirror_sigmas},
                                         params["base"], True)}
    print(json.dumps(result, indent=1))
    if args.out:
        atomic_write_json(args.out, result)


if __name__ == "__main__":
    main()
