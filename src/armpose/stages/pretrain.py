"""Stage ``pretrain``: full training from scratch on the UR robots (UR3, UR5, UR10).

Reads ``params["base"]`` and ``params["pretrain"]``; see :mod:`armpose.stages.training`.
"""
from armpose.stages.training import stage_functions

run, main = stage_functions("pretrain", __doc__)

if __name__ == "__main__":
    main()
