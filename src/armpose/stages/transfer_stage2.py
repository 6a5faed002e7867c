"""Stage ``transfer_stage2``: unfreeze the second group of conv layers as well and continue until the plateau.

Reads ``params["base"]`` and ``params["transfer_stage2"]``; see :mod:`armpose.stages.training`.
"""
from armpose.stages.training import stage_functions

run, main = stage_functions("transfer_stage2", __doc__)

if __name__ == "__main__":
    main()
