"""Adding a robot type is a description plus data: register xArm6 from a YAML file and render it."""
import numpy as np
import yaml

from armpose.config import profile_params
from armpose.labels.compute import label_recording
from armpose.robots import get_robot, register_file
from armpose.sim.render import RenderJob, render_recording

XARM = {
    "name": "xarm6", "family": "xArm",
    "urdf": {"source": "pybullet_data", "path": "xarm/xarm6_robot.urdf"},
    "base_link": "link_base",
    "joints": ["joint1", "joint2", "joint3", "joint4", "joint5", "joint6"],
    "joint_limits": [[-6.28, 6.28], [-2.05, 2.09], [-3.92, 0.19], [-6.28, 6.28], [-1.69, 3.14], [-6.28, 6.28]],
    "reach": 0.7,
    "appearance": {"default_color": [0.9, 0.9, 0.9, 1.0], "link_colors": {}},
}


def test_register_render_and_label_a_sixth_robot(tmp_path):
    path = tmp_path / "xarm6.yaml"
    path.write_text(yaml.safe_dump(XARM))
    spec = register_file(path)
    assert get_robot("xarm6") is spec
    params = profile_params("quick")
    types = (*params["base"]["robot_types"], "xarm6")
    job = RenderJob("xarm6", 3, (1, 2, 3), tmp_path / "xarm6_000", params["base"]["camera"], params["render"], types)
    render_recording(job)
    arrays, meta, skipped = label_recording(job.out_dir, params["base"]["input_size"], 7)
    assert meta.robot == "xarm6" and not skipped
    assert arrays["masks"].reshape(3, -1).sum(1).min() > 50
    assert arrays["joint_valid"].sum(1).tolist() == [6, 6, 6]
    assert np.isfinite(arrays["joints"]).all()
