"""Stage ``train_full``: the paper's comparison, the same network trained from scratch on all five robot
types with the same data budget as the transfer stages.

Reads ``params["base"]`` and ``params["train_full"]``; see :mod:`armpose.stages.training`.
"""
from armpose.stages.training import stage_functions

run, main = stage_functions("train_full", __doc__)

if __name__ == "__main__":
    main()
