"""armpose: robot detection, type classification and 3D joint estimation from one RGB image.

A reproduction of Miseikis et al. 2019 (two-stage transfer learning for
heterogeneous robot detection). See README.md for the pipeline.
"""

__version__ = "0.1.0"
