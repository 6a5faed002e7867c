"""Stage ``transfer_stage1``: from the pretrained weights, train only the final layers on the transfer set
(N frames per robot type, UR included) until the loss plateaus.

Reads ``params["base"]`` and ``params["transfer_stage1"]``; see :mod:`armpose.stages.training`.
"""
from armpose.stages.training import stage_functions

run, main = stage_functions("transfer_stage1", __doc__)

if __name__ == "__main__":
    main()
