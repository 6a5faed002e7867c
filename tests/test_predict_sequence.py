"""``armpose predict --sequence`` and :func:`armpose.sequence.predict_sequence` with an oracle network.

Each frame is one uniform colour encoding its index; the oracle answers with the base and joints
of a UR5 moving smoothly (camera optical frame, metres) under a static ``T_cam_base``, plus noise.
"""
import functools
import json
import shutil

import cv2
import numpy as np
import pytest
import torch
from torch import nn

from armpose import predict_cli
from armpose.camera_pose import rotation_error_deg, translation_error_m
from armpose.config import profile_params
from armpose.extrinsics import kinematics
from armpose.geometry import Camera, invert, look_at
from armpose.model import build_model
from armpose.robots import get_robot
from armpose.sequence import iter_sequence, predict_sequence
from armpose.tracking import jitter, median_error
from armpose.train import save_checkpoint

ROBOT = "ur5"
RATE_HZ = 30.0
T_CAM_BASE = invert(look_at(np.array([1.6, -1.2, 1.1]), np.array([0.0, 0.0, 0.35]), roll=-0.05))
SCHEMA = {"image", "robot_type", "type_probs", "base_xyz", "joints_xyz", "joints_uv", "latency_ms", "frame", "time_s",
          "raw_robot_type", "raw_joints_xyz", "raw_base_xyz"}
POSE_KEYS = {"T_cam_base", "raw_T_cam_base", "pose_rmse_m"}


def code_image(i: int, cam: Camera) -> np.ndarray:
    """A uniform RGB image whose colour encodes ``i`` (16 levels per channel, robust to JPEG)."""
    rgb = [16 * (i % 16) + 8, 16 * ((i // 16) % 16) + 8, 16 * (i // 256) + 8]
    return np.broadcast_to(np.array(rgb, np.uint8), (cam.height, cam.width, 3)).copy()


class TableOracle(nn.Module):
    """Decodes :func:`code_image`'s index ``i`` from its input; answers ``joints[i]``, ``base[i]``."""

    def __init__(self, joints: np.ndarray, base: np.ndarray, type_index: int, num_types: int = 5, slots: int = 7):
        super().__init__()
        self.joints, self.base, self.k, self.n, self.slots = joints, base, type_index, num_types, slots

    def forward(self, x):
        c = (x[0, :, x.shape[2] // 2, x.shape[3] // 2].double() * 255 - 8) / 16
        r, g, b = (round(float(v)) for v in c)
        i = r + 16 * g + 256 * b
        j = torch.zeros(1, self.slots, 3, dtype=torch.float64)
        j[0, :self.joints.shape[1]] = torch.from_numpy(self.joints[i])
        logits = torch.full((1, self.n), -5.0)
        logits[0, self.k] = 5.0
        return {"joints": j, "base": torch.from_numpy(self.base[i])[None], "type_logits": logits,
                "mask_logits": torch.full((1, 1, x.shape[2], x.shape[3]), -10.0)}


def smooth_angles(n: int, seed: int = 0) -> np.ndarray:
    """UR5 joint angles ``(n, 6)``: sinusoids of 0.35 rad, 0.2-0.4 Hz, about a bent pose, at RATE_HZ."""
    rng = np.random.default_rng(seed)
    t = np.arange(n)[:, None] / RATE_HZ
    q0 = np.array([0.3, -1.2, 1.3, -0.8, -1.4, 0.2])
    return q0 + 0.35 * np.sin(2 * np.pi * rng.uniform(0.2, 0.4, 6) * t + rng.uniform(0, 2 * np.pi, 6))


def truth(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """True joints ``(N, 6, 3)`` and base ``(N, 3)`` in the camera frame."""
    fk = kinematics(ROBOT).joint_positions(q)
    return fk @ T_CAM_BASE[:3, :3].T + T_CAM_BASE[:3, 3], np.tile(T_CAM_BASE[:3, 3], (len(q), 1))


def oracle(joints, base, noise_m: float, types, seed: int = 0) -> TableOracle:
    rng = np.random.default_rng(seed)
    return TableOracle(joints + rng.normal(0, noise_m, joints.shape), base + rng.normal(0, noise_m, base.shape),
                       types.index(ROBOT))


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """A tiny checkpoint, its camera, and a folder of 90 coded frames of a smooth UR5 motion."""
    tmp = tmp_path_factory.mktemp("sequence")
    base = profile_params("quick")["base"]
    base["model"] = {"width": 4}
    ckpt = tmp / "model.pt"
    save_checkpoint(ckpt, build_model(base["model"]), None, None, 0, "transfer_stage2",
                    {"stage": "transfer_stage2", "cfg": {}, "base": base})
    cam = Camera.from_dict(base["camera"])
    q = smooth_angles(90)
    (tmp / "frames").mkdir()
    for i in range(len(q)):
        cv2.imwrite(str(tmp / "frames" / f"{i:06d}.png"), code_image(i, cam)[..., ::-1])
    return tmp, base, ckpt, cam, q


def joints_of(rows, key="joints_xyz") -> np.ndarray:
    return np.array([r[key] for r in rows], dtype=np.float64)


@pytest.mark.parametrize("filt", ["kalman", "one-euro"])
def test_the_filter_halves_jitter_without_raising_the_error(setup, filt):
    tmp, base, ckpt, cam, q = setup
    joints, base_xyz = truth(q)
    rows = predict_sequence([tmp / "frames"], ckpt, filter=filt, model=oracle(joints, base_xyz, 0.02, base["robot_types"]),
                            joint_angles=q, robot=ROBOT)
    assert len(rows) == len(q) and all(set(r) == SCHEMA | POSE_KEYS for r in rows)
    raw, filtered = joints_of(rows, "raw_joints_xyz"), joints_of(rows)
    j_raw, j_f = float(np.mean(jitter(raw))), float(np.mean(jitter(filtered)))
    e_raw, e_f = median_error(raw, joints), median_error(filtered, joints)
    rb, fb = joints_of(rows, "raw_base_xyz"), joints_of(rows, "base_xyz")
    T_raw, T_f = joints_of(rows, "raw_T_cam_base"), joints_of(rows, "T_cam_base")
    rot = [np.median(rotation_error_deg(T, T_CAM_BASE)) for T in (T_raw, T_f)]
    trans = [np.median(translation_error_m(T, T_CAM_BASE)) for T in (T_raw, T_f)]
    print(f"\n{filt}: joint jitter {j_raw * 1000:.2f} -> {j_f * 1000:.2f} mm/frame^2 ({j_raw / j_f:.1f}x), median joint "
          f"error {e_raw * 1000:.1f} -> {e_f * 1000:.1f} mm ({e_f / e_raw:.2f}x); base jitter "
          f"{jitter(rb) * 1000:.2f} -> {jitter(fb) * 1000:.2f}; pose median rotation {rot[0]:.2f} -> {rot[1]:.2f} deg, "
          f"translation {trans[0] * 1000:.1f} -> {trans[1] * 1000:.1f} mm")
    assert j_f < 0.5 * j_raw
    assert e_f <= 1.05 * e_raw
    assert jitter(fb) < 0.5 * jitter(rb)
    assert rot[1] < rot[0] and trans[1] < trans[0]
    uv = np.array([r["joints_uv"] for r in rows])
    np.testing.assert_allclose(uv, cam.project(filtered), atol=1e-9)       # uv from the smoothed 3D points


@pytest.mark.parametrize("filt", ["kalman", "one-euro", "none"])
def test_changing_a_later_frame_never_changes_earlier_outputs(setup, filt):
    tmp, base, ckpt, cam, q = setup
    n, m = 30, 20
    joints, base_xyz = truth(q[:n])
    # table entries n.. are frames 0.. moved by 0.3 m: frame m re-coded to entry n + m differs from m
    table = oracle(np.concatenate([joints, joints + 0.3]), np.concatenate([base_xyz, base_xyz + 0.3]), 0.01,
                   base["robot_types"])
    folder = tmp / f"causal_{filt}"
    shutil.copytree(tmp / "frames", folder)
    for f in sorted(folder.iterdir())[n:]:
        f.unlink()
    run = functools.partial(predict_sequence, [folder], ckpt, filter=filt, model=table, joint_angles=q[:n], robot=ROBOT)
    before = run()
    cv2.imwrite(str(folder / f"{m:06d}.png"), code_image(n + m, cam)[..., ::-1])
    after = run()
    strip = [{k: v for k, v in r.items() if k != "latency_ms"} for r in (*before, *after)]
    assert strip[:m] == strip[n:n + m]
    for k in range(m, n):
        assert strip[k]["T_cam_base"] != strip[n + k]["T_cam_base"] or filt == "none"
        assert strip[k]["joints_xyz"] != strip[n + k]["joints_xyz"] or (filt == "none" and k > m)


def test_a_video_file_is_read_frame_by_frame_in_order(setup):
    tmp, base, ckpt, cam, q = setup
    n = 12
    video = tmp / "clip.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (cam.width, cam.height))
    assert writer.isOpened()
    for i in range(n):
        writer.write(code_image(i, cam)[..., ::-1].copy())
    writer.release()
    joints, base_xyz = truth(q[:n])
    rows = predict_sequence([video], ckpt, filter="none", rate_hz=None, model=oracle(joints, base_xyz, 0.0,
                                                                                  base["robot_types"]))
    assert [r["image"] for r in rows] == [f"{video}#{i}" for i in range(n)]
    assert [r["time_s"] for r in rows] == [round(i / 25.0, 6) for i in range(n)]     # the video's own rate
    np.testing.assert_allclose(joints_of(rows), joints, atol=1e-12)               # every frame decoded to its index
    assert all(set(r) == SCHEMA for r in rows)


def test_cli_sequence_on_a_video_with_joints_writes_jsonl_with_the_pose(setup, monkeypatch, capsys):
    tmp, base, ckpt, cam, q = setup
    n = 10
    video = tmp / "cli_clip.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (cam.width, cam.height))
    for i in range(n):
        writer.write(code_image(i, cam)[..., ::-1].copy())
    writer.release()
    joints, base_xyz = truth(q[:n])
    monkeypatch.setattr(predict_cli, "iter_sequence",
                        functools.partial(iter_sequence, model=oracle(joints, base_xyz, 0.0, base["robot_types"])))
    csv = tmp / "cli_joints.csv"
    csv.write_text("image," + ",".join(get_robot(ROBOT).joints) + "\n"
                   + "".join(f"cli_clip.avi#{i}," + ",".join(f"{v:.17g}" for v in q[i]) + "\n" for i in reversed(range(n))))
    out, overlays, masks = tmp / "seq.jsonl", tmp / "seq_overlays", tmp / "seq_masks"
    args = ["--checkpoint", str(ckpt), "--sequence", "--joints", str(csv), "--robot", ROBOT, "--out", str(out),
            "--overlays", str(overlays), "--masks", str(masks), str(video)]
    assert predict_cli.main(args) == 0, capsys.readouterr().err
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(rows) == n and all(set(r) == SCHEMA | POSE_KEYS | {"mask"} for r in rows)
    assert [r["mask"].rsplit("/", 1)[1] for r in rows] == [f"cli_clip_{i:06d}_mask.png" for i in range(n)]
    for r in rows:
        assert rotation_error_deg(np.asarray(r["T_cam_base"]), T_CAM_BASE) < 1e-4
        assert translation_error_m(np.asarray(r["T_cam_base"]), T_CAM_BASE) < 1e-6
    assert len(list(overlays.glob("cli_clip_*_overlay.png"))) == n
    csv.write_text("\n".join(csv.read_text().splitlines()[:-1]) + "\n")           # one frame without a row
    assert predict_cli.main(args) == 1
    err = capsys.readouterr().err
    assert "cli_joints.csv" in err and "cli_clip.avi#0" in err and "no row" in err


def test_sequence_options_need_sequence(setup, capsys):
    tmp, base, ckpt, cam, q = setup
    with pytest.raises(SystemExit):
        predict_cli.main(["--checkpoint", str(ckpt), "--filter", "kalman", str(tmp / "frames")])
    assert "only with --sequence" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        predict_cli.main(["--checkpoint", str(ckpt), "--sequence", "--joints", "j.csv", str(tmp / "frames")])
    assert "--joints needs --robot" in capsys.readouterr().err
