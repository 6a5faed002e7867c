"""Automatic labels from a recording: the paper's MoveIt step, redone with PyBullet and pytorch-kinematics."""
