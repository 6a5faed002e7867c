"""Stage ``transfer_stage2``: unfreeze the second group of conv layers as well and continue until the plateau.

Reads ``params["base"]`` and ``params["transfer_stage2"]``; see :mod:`armpose.stages.training`.
With ``fit_sigmas: true``, the kinematic fit's weights are then measured per robot type on
held-out training frames and stored in the checkpoint (:mod:`armpose.fit_sigmas`); with
``fit_sigmas_on_mirror: true`` on the mirror test's passes, the estimates that ``evaluate``
with ``zoom_on_mirror`` and ``armpose predict --mirror --zoom --fit`` fit.
"""
from pathlib import Path

from armpose.fit_sigmas import add_fit_sigmas
from armpose.labels.dataset import load_dataset
from armpose.stages.training import stage_functions
from armpose.train import training_rows


def measure_fit_sigmas(cfg: dict, base: dict, root: Path, out: Path) -> dict:
    """``{"fit_sigmas": ...}`` of the trained network when ``cfg`` asks for them, else ``{}``."""
    if not cfg.get("fit_sigmas", False):
        return {}
    data = root / "data" / "labels"
    used = training_rows(load_dataset(data)[0], cfg, base)
    return {"fit_sigmas": add_fit_sigmas(out / "model.pt", data, used, int(base["seed"]),
                                         on_mirror=bool(cfg.get("fit_sigmas_on_mirror", False)))}


run, main = stage_functions("transfer_stage2", __doc__, after=measure_fit_sigmas)

if __name__ == "__main__":
    main()
