"""``armpose calibrate`` and :mod:`armpose.extrinsics` with an oracle network.

The oracle stands in for the network: each image is one uniform colour that encodes its index,
and the oracle answers with the true base and joint positions of a UR5 at that image's joint
angles under a known ``T_cam_base`` (camera optical frame, metres), plus optional Gaussian noise.
"""
import functools
import json

import cv2
import numpy as np
import pytest
import torch
from torch import nn

from armpose import calibrate_cli
from armpose.camera_pose import rotation_error_deg, translation_error_m
from armpose.config import profile_params
from armpose.extrinsics import estimate_extrinsics, kinematics, read_joint_csv
from armpose.geometry import Camera, invert, look_at, quat_to_matrix
from armpose.model import build_model
from armpose.predict import predict
from armpose.robots import get_robot
from armpose.train import save_checkpoint

ROBOT = "ur5"
T_CAM_BASE = invert(look_at(np.array([1.7, -1.1, 1.2]), np.array([0.0, 0.0, 0.35]), roll=0.1))
N_IMAGES = 10


def code_image(i: int, cam: Camera) -> np.ndarray:
    """A uniform RGB image whose colour encodes ``i`` (16 levels per channel, robust to JPEG)."""
    rgb = [16 * (i % 16) + 8, 16 * ((i // 16) % 16) + 8, 16 * (i // 256) + 8]
    return np.broadcast_to(np.array(rgb, np.uint8), (cam.height, cam.width, 3)).copy()


def decode(x: torch.Tensor) -> int:
    """The index of :func:`code_image` from a network input ``(1, 3, H, W)`` in [0, 1]."""
    c = (x[0, :, x.shape[2] // 2, x.shape[3] // 2].double() * 255 - 8) / 16
    r, g, b = (round(float(v)) for v in c)
    return r + 16 * g + 256 * b


class TableOracle(nn.Module):
    """Answers image ``i`` with ``joints[i]`` ``(J, 3)`` and ``base[i]`` ``(3,)`` (camera frame, m)."""

    def __init__(self, joints: np.ndarray, base: np.ndarray, type_index: int, num_types: int = 5, slots: int = 7):
        super().__init__()
        self.joints, self.base, self.k, self.n, self.slots = joints, base, type_index, num_types, slots

    def forward(self, x):
        i = decode(x)
        j = torch.zeros(1, self.slots, 3, dtype=torch.float64)
        j[0, :self.joints.shape[1]] = torch.from_numpy(self.joints[i])
        logits = torch.full((1, self.n), -5.0)
        logits[0, self.k] = 5.0
        return {"joints": j, "base": torch.from_numpy(self.base[i])[None], "type_logits": logits,
                "mask_logits": torch.full((1, 1, x.shape[2], x.shape[3]), -10.0)}


def oracle_for(q: np.ndarray, noise_m: float, seed: int, types: list[str]) -> TableOracle:
    """The oracle of a UR5 at angles ``q (N, J)`` seen under :data:`T_CAM_BASE`, noise ``noise_m`` per axis."""
    rng = np.random.default_rng(seed)
    fk = kinematics(ROBOT).joint_positions(q)
    joints = fk @ T_CAM_BASE[:3, :3].T + T_CAM_BASE[:3, 3] + rng.normal(0, noise_m, fk.shape)
    base = np.tile(T_CAM_BASE[:3, 3], (len(q), 1)) + rng.normal(0, noise_m, (len(q), 3))
    return TableOracle(joints, base, types.index(ROBOT))


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """A tiny checkpoint, N_IMAGES coded images and UR5 joint angles for them."""
    tmp = tmp_path_factory.mktemp("calibrate")
    base = profile_params("quick")["base"]
    base["model"] = {"width": 4}
    ckpt = tmp / "model.pt"
    save_checkpoint(ckpt, build_model(base["model"]), None, None, 0, "transfer_stage2",
                    {"stage": "transfer_stage2", "cfg": {}, "base": base})
    cam = Camera.from_dict(base["camera"])
    (tmp / "images").mkdir()
    for i in range(N_IMAGES):
        cv2.imwrite(str(tmp / "images" / f"{i:03d}.png"), code_image(i, cam)[..., ::-1])
    q = np.random.default_rng(1).uniform(-1.4, 1.4, (N_IMAGES, get_robot(ROBOT).num_joints))
    return tmp, base, ckpt, q


def write_joints(path, q, key="frame", names=None):
    """A JOINTS.csv of angles ``q``; ``names`` for an ``image`` column."""
    joints = get_robot(ROBOT).joints
    lines = [f"{key}," + ",".join(joints)]
    for i, row in enumerate(q):
        lines.append(f"{names[i] if names else i}," + ",".join(f"{v:.12f}" for v in row))
    path.write_text("\n".join(lines) + "\n")
    return path


def errors_of(result: dict) -> tuple[float, float]:
    """(rotation deg, translation m) of a result's T_cam_base against the truth."""
    T = np.asarray(result["T_cam_base"])
    return rotation_error_deg(T, T_CAM_BASE), translation_error_m(T, T_CAM_BASE)


def predictions(setup, noise_m, seed=0):
    tmp, base, ckpt, q = setup
    oracle = oracle_for(q, noise_m, seed, base["robot_types"])
    return predict([tmp / "images"], ckpt, model=oracle)


@pytest.mark.parametrize("pooled,refine", [(True, False), (False, False), (True, True), (True, "rays"), (False, "rays")])
def test_zero_noise_recovers_the_pose_within_a_millimetre_and_a_tenth_of_a_degree(setup, pooled, refine):
    tmp, base, ckpt, q = setup
    preds = predictions(setup, 0.0)
    assert [p["robot_type"] for p in preds] == [ROBOT] * N_IMAGES
    res = estimate_extrinsics(preds, q, ROBOT, pooled=pooled, refine_2d=refine is True,
                              camera=Camera.from_dict(base["camera"]), refine_rays_depth=refine == "rays")
    assert res["refine_rays"] == (refine == "rays")
    rot, trans = errors_of(res)
    print(f"zero noise pooled={pooled} refine_2d={refine}: rotation {rot:.2e} deg, translation {trans:.2e} m")
    assert rot < 0.1 and trans < 1e-3
    assert res["images_used"] == N_IMAGES and res["points_used"] == N_IMAGES * 7 and res["rmse_m"] < 1e-4
    np.testing.assert_allclose(np.asarray(res["T_base_cam"]) @ np.asarray(res["T_cam_base"]), np.eye(4), atol=1e-9)
    np.testing.assert_allclose(quat_to_matrix(np.asarray(res["quaternion_xyzw"])), T_CAM_BASE[:3, :3], atol=1e-4)
    assert res["reprojection_rmse_px"] < 0.5


def test_ten_pooled_images_beat_one_at_two_centimetres_of_noise(setup):
    tmp, base, ckpt, q = setup
    single, pooled = [], []
    for seed in range(4):
        preds = predictions(setup, 0.02, seed)
        pooled.append(errors_of(estimate_extrinsics(preds, q, ROBOT)))
        single += [errors_of(estimate_extrinsics(preds[i:i + 1], q[i:i + 1], ROBOT)) for i in range(N_IMAGES)]
    single, pooled = np.median(single, axis=0), np.median(pooled, axis=0)
    print(f"2 cm noise, median over trials: single image {single[0]:.2f} deg {single[1] * 1000:.1f} mm; "
          f"10 pooled {pooled[0]:.2f} deg {pooled[1] * 1000:.1f} mm")
    assert pooled[0] < 0.6 * single[0] and pooled[1] < 0.6 * single[1]


def test_a_gross_outlier_is_reported_and_does_not_move_the_pose(setup):
    tmp, base, ckpt, q = setup
    preds = predictions(setup, 0.0)
    preds[3]["joints_xyz"][2] = [5.0, 5.0, 9.0]
    res = estimate_extrinsics(preds, q, ROBOT)
    rot, trans = errors_of(res)
    assert rot < 0.1 and trans < 1e-3
    assert res["per_image"][3]["outliers"] == [get_robot(ROBOT).joints[2]]
    assert res["per_point"][get_robot(ROBOT).joints[2]]["inlier_fraction"] == 0.9


@pytest.fixture
def cli(setup, monkeypatch):
    """``armpose calibrate`` with the noise-free oracle in place of the network."""
    tmp, base, ckpt, q = setup
    oracle = oracle_for(q, 0.0, 0, base["robot_types"])
    monkeypatch.setattr(calibrate_cli, "predict", functools.partial(predict, model=oracle))
    return lambda *args: calibrate_cli.main(["--checkpoint", str(ckpt), *map(str, args)])


@pytest.mark.parametrize("key", ["frame", "image"])
def test_cli_writes_the_pose_its_inverse_and_the_residuals_as_json(setup, cli, capsys, key):
    tmp, base, ckpt, q = setup
    order = np.random.default_rng(2).permutation(N_IMAGES) if key == "image" else np.arange(N_IMAGES)
    names = [f"{i:03d}.png" for i in order] if key == "image" else None
    joints = write_joints(tmp / f"joints_{key}.csv", q[order], key, names)
    out = tmp / "out" / f"extrinsics_{key}.json"
    rc = cli("--joints", joints, "--out", out, "--refine-2d", tmp / "images")
    assert rc == 0, capsys.readouterr().err
    res = json.loads(out.read_text())
    rot, trans = errors_of(res)
    assert rot < 0.1 and trans < 1e-3
    assert res["robot"] == ROBOT and res["inputs"]["robot_from"].startswith("majority")
    T_base_cam = np.asarray(res["T_base_cam"])
    np.testing.assert_allclose(T_base_cam, invert(T_CAM_BASE), atol=1e-3)
    np.testing.assert_allclose(res["T_base_cam_translation_m"], T_base_cam[:3, 3])
    assert abs(np.linalg.norm(res["quaternion_xyzw"]) - 1) < 1e-9
    assert len(res["per_image"]) == N_IMAGES and res["images_used"] == N_IMAGES
    first = res["per_image"][0]
    assert set(first["residuals_m"]) == {"base", *get_robot(ROBOT).joints} and first["inliers"] == 7
    assert "translation" in capsys.readouterr().out


def test_refine_rays_and_refine_2d_exclude_each_other(setup, cli, capsys):
    tmp, base, ckpt, q = setup
    with pytest.raises(ValueError, match="choose one"):
        estimate_extrinsics(predictions(setup, 0.0), q, ROBOT, refine_2d=True, refine_rays_depth=True,
                            camera=Camera.from_dict(base["camera"]))
    joints = write_joints(tmp / "joints_rays.csv", q, "frame", None)
    with pytest.raises(SystemExit):
        cli("--joints", joints, "--refine-rays", "--refine-2d", tmp / "images")
    assert "not allowed with argument" in capsys.readouterr().err
    assert cli("--joints", joints, "--refine-rays", "--out", tmp / "rays.json", tmp / "images") == 0
    rot, trans = errors_of(json.loads((tmp / "rays.json").read_text()))
    assert rot < 0.1 and trans < 1e-3


BAD = [  # (what to do to a good frame-keyed file, text the error must contain)
    (lambda lines: lines[:3] + ["2,0.1,0.2,abc,0.4,0.5,0.6"] + lines[4:], [":4:", "abc", "elbow_joint"]),
    (lambda lines: lines[:5] + ["4,0.1,0.2,0.3,0.4,0.5"] + lines[6:], [":6:", "expected 7 columns"]),
    (lambda lines: lines[:7] + ["6,0.1,0.2,nan,0.4,0.5,0.6"] + lines[8:], [":8:", "nan"]),
    (lambda lines: lines[:3] + ["1" + lines[3][1:]] + lines[4:], [":4:", "must increase", "'1'"]),
    (lambda lines: [lines[0].replace("wrist_3_joint", "wrist_9_joint")] + lines[1:], [":1:", "wrist_9_joint"]),
    (lambda lines: [lines[0].replace("frame", "time")] + lines[1:], [":1:", "'time'"]),
    (lambda lines: lines[:-1], ["9 rows", "10 images"]),
]


@pytest.mark.parametrize("edit,expect", BAD)
def test_a_bad_joints_csv_is_one_error_naming_file_row_and_value(setup, cli, capsys, edit, expect):
    tmp, base, ckpt, q = setup
    good = write_joints(tmp / "good.csv", q).read_text().splitlines()
    bad = tmp / "bad_joints.csv"
    bad.write_text("\n".join(edit(good)) + "\n")
    rc = cli("--joints", bad, "--robot", ROBOT, "--out", tmp / "never.json", tmp / "images")
    err = capsys.readouterr().err
    assert rc == 1 and "bad_joints.csv" in err
    for text in expect:
        assert text in err, (text, err)
    assert not (tmp / "never.json").exists()


def test_an_image_without_a_row_is_named(setup, cli, capsys):
    tmp, base, ckpt, q = setup
    names = [f"{i:03d}.png" for i in range(N_IMAGES)]
    names[4] = "other.png"
    joints = write_joints(tmp / "named.csv", q, "image", names)
    assert cli("--joints", joints, tmp / "images") == 1
    err = capsys.readouterr().err
    assert "named.csv" in err and "004.png" in err and "no row" in err
    with pytest.raises(ValueError, match="named.csv"):
        read_joint_csv(tmp / "named.csv").angles_for(get_robot("iiwa").joints)
