"""``armpose predict``: the warp round trip with an oracle network, the JSONL schema, bad input."""
import json

import cv2
import numpy as np
import pytest
import torch
from torch import nn

from armpose.config import profile_params
from armpose.geometry import Camera
from armpose.model import build_model
from armpose.labels.compute import scale_crop_image
from armpose.predict import PredictError, network_camera, predict, read_image, to_network, warp_for
from armpose.predict_cli import main as predict_main
from armpose.train import save_checkpoint

OTHER = Camera(640, 480, 600.0, 590.0, 331.0, 236.5)      # a user's camera, not the canonical one
SCHEMA = {"image", "robot_type", "type_probs", "base_xyz", "joints_xyz", "joints_uv", "latency_ms"}


class BlobOracle(nn.Module):
    """Stands in for the network: finds the one bright blob in its input (intensity centroid,
    in network-input pixels), and returns every joint and the base at that pixel's ray at
    depth ``z``; predicts robot type ``type_index``; the mask is the bright pixels. With
    ``radius_m``, the depth comes from the blob's apparent size instead, as a network's does:
    a disc of that radius in metres, of area ``pi (fx radius_m / z)^2`` pixels."""

    def __init__(self, net: Camera, z: float, type_index: int, num_types: int = 5, slots: int = 7,
                 radius_m: float | None = None):
        super().__init__()
        self.net, self.z, self.k, self.n, self.slots, self.radius_m = net, z, type_index, num_types, slots, radius_m

    def forward(self, x):
        gray = x.float().mean(1)                                               # (B, H, W)
        w = gray.clamp(min=0).double()
        s = w.sum((1, 2))
        u = (w.sum(1) * torch.arange(gray.shape[2], dtype=torch.float64)).sum(1) / s
        v = (w.sum(2) * torch.arange(gray.shape[1], dtype=torch.float64)).sum(1) / s
        z = (torch.full_like(u, self.z) if self.radius_m is None
             else self.net.fx * self.radius_m / torch.sqrt(s / np.pi))
        p = torch.stack([(u - self.net.cx) / self.net.fx * z, (v - self.net.cy) / self.net.fy * z, z], -1)
        logits = torch.full((x.shape[0], self.n), -5.0)
        logits[:, self.k] = 5.0
        return {"joints": p[:, None].expand(-1, self.slots, 3).clone(), "base": p.clone(), "type_logits": logits,
                "mask_logits": (gray > 0.5).float()[:, None] * 20 - 10}


def blob_image(cam: Camera, point: np.ndarray, radius_px: float = 5.0) -> np.ndarray:
    """Black image of ``cam`` with one anti-aliased white disc centred on ``point``'s projection."""
    u, v = cam.project(point)
    ys, xs = np.mgrid[0:cam.height, 0:cam.width]
    d = np.hypot(xs - u, ys - v)
    img = np.clip(radius_px + 0.5 - d, 0, 1)
    return (np.repeat(img[..., None], 3, 2) * 255).round().astype(np.uint8)


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("predict")
    base = profile_params("quick")["base"]
    base["model"] = {"width": 4}
    ckpt = tmp / "model.pt"
    save_checkpoint(ckpt, build_model(base["model"]), None, None, 0, "transfer_stage2",
                    {"stage": "transfer_stage2", "cfg": {}, "base": base})
    return tmp, base, ckpt


def _write_png(path, rgb):
    cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))


POINTS = np.array([[0.12, -0.08, 1.6], [-0.35, 0.2, 2.4], [0.5, 0.3, 3.1], [-0.1, -0.25, 1.2]])


def test_warp_round_trip_with_an_oracle_is_within_one_pixel(setup):
    tmp, base, ckpt = setup
    canonical = Camera.from_dict(base["camera"])
    net = network_camera(base)
    (tmp / "other").mkdir()
    (tmp / "canon").mkdir()
    cams = (json.dumps(OTHER.to_dict()),)
    (tmp / "other.json").write_text(cams[0])
    for i, p in enumerate(POINTS):
        _write_png(tmp / "other" / f"{i}.png", blob_image(OTHER, p))
        _write_png(tmp / "canon" / f"{i}.png", blob_image(canonical, p))
    type_index = base["robot_types"].index("iiwa")
    for i, p in enumerate(POINTS):
        oracle = BlobOracle(net, float(p[2]), type_index)
        other = predict([tmp / "other" / f"{i}.png"], ckpt, tmp / "other.json", model=oracle)[0]
        canon = predict([tmp / "canon" / f"{i}.png"], ckpt, model=oracle)[0]
        assert other["robot_type"] == "iiwa" and len(other["joints_uv"]) == 7
        err_other = np.abs(np.asarray(other["joints_uv"][0]) - OTHER.project(p)).max()
        err_canon = np.abs(np.asarray(canon["joints_uv"][0]) - canonical.project(p)).max()
        assert err_other < 1.0, (i, other["joints_uv"][0], OTHER.project(p))
        assert err_canon < 1.0, (i, canon["joints_uv"][0], canonical.project(p))
        # the same 3D answer from both cameras: the warp changes pixels, never the optical frame
        np.testing.assert_allclose(other["joints_xyz"][0], canon["joints_xyz"][0], atol=0.01 * p[2])


def test_mirror_test_keeps_an_exact_oracle_exact_through_the_warp(setup):
    tmp, base, ckpt = setup
    (tmp / "mirror").mkdir()
    (tmp / "other.json").write_text(json.dumps(OTHER.to_dict()))
    for i, p in enumerate(POINTS):
        _write_png(tmp / "mirror" / f"{i}.png", blob_image(OTHER, p))
        row = predict([tmp / "mirror" / f"{i}.png"], ckpt, tmp / "other.json",
                      model=BlobOracle(network_camera(base), float(p[2]), 0), mirror=True)[0]
        assert np.abs(np.asarray(row["joints_uv"][0]) - OTHER.project(p)).max() < 1.0
        np.testing.assert_allclose(row["base_xyz"], p, atol=0.01 * p[2])


@pytest.mark.parametrize("mirror", [False, True])
def test_zoom_test_keeps_an_exact_oracle_exact_through_the_warp(setup, mirror):
    """The second, magnified look of ``--zoom`` maps back to the truth: an oracle that reads depth
    from apparent size, on a user's camera, gives the true point and pixel with and without it."""
    tmp, base, ckpt = setup
    folder = tmp / f"zoom{int(mirror)}"
    folder.mkdir()
    (tmp / "other.json").write_text(json.dumps(OTHER.to_dict()))
    radius_m = 0.1
    for i, p in enumerate(POINTS):
        _write_png(folder / f"{i}.png", blob_image(OTHER, p, OTHER.fx * radius_m / p[2]))
        oracle = BlobOracle(network_camera(base), 0.0, 0, radius_m=radius_m)
        plain, zoomed = (predict([folder / f"{i}.png"], ckpt, tmp / "other.json", model=oracle, mirror=mirror,
                                 zoom=zoom)[0] for zoom in (False, True))
        assert np.abs(np.asarray(zoomed["joints_uv"][0]) - OTHER.project(p)).max() < 1.0
        np.testing.assert_allclose(zoomed["base_xyz"], p, atol=0.02 * p[2])
        np.testing.assert_allclose(zoomed["base_xyz"], plain["base_xyz"], atol=0.01 * p[2])


def test_a_point_outside_the_canonical_view_is_padded_not_lost(setup):
    tmp, base, ckpt = setup
    wide = Camera(320, 240, 150.0, 150.0, 159.5, 119.5)          # wider field of view: scaled up and cropped
    p = np.array([0.2, 0.1, 2.0])
    _write_png(tmp / "wide.png", blob_image(wide, p, 3.0))
    oracle = BlobOracle(network_camera(base), 2.0, 0)
    row = predict([tmp / "wide.png"], ckpt, wide, model=oracle)[0]
    assert np.abs(np.asarray(row["joints_uv"][0]) - wide.project(p)).max() < 1.0


def test_cli_writes_jsonl_in_the_schema_and_reports_bad_files(setup, capsys):
    tmp, base, ckpt = setup
    folder = tmp / "mixed"
    folder.mkdir()
    rng = np.random.default_rng(0)
    cam = Camera.from_dict(base["camera"])
    for i in range(2):
        _write_png(folder / f"ok{i}.png", rng.integers(0, 255, (cam.height, cam.width, 3), dtype=np.uint8))
    (folder / "broken.png").write_text("not an image")
    _write_png(folder / "small.png", np.zeros((10, 12, 3), np.uint8))
    out, masks, overlays = tmp / "preds.jsonl", tmp / "masks", tmp / "overlays"
    rc = predict_main(["--checkpoint", str(ckpt), "--out", str(out), "--masks", str(masks), "--overlays",
                       str(overlays), "--mirror", "--zoom", str(folder), str(tmp / "missing.png")])
    err = capsys.readouterr().err
    assert rc == 1
    assert "broken.png" in err and "not a readable image" in err
    assert "small.png" in err and "12x10" in err
    assert "missing.png" in err
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    assert [r["image"].rsplit("/", 1)[1] for r in rows] == ["ok0.png", "ok1.png"]
    for r in rows:
        assert set(r) == SCHEMA | {"mask"}
        assert r["robot_type"] in base["robot_types"] and set(r["type_probs"]) == set(base["robot_types"])
        assert abs(sum(r["type_probs"].values()) - 1) < 1e-5
        n = {"ur3": 6, "ur5": 6, "ur10": 6, "iiwa": 7, "panda": 7}[r["robot_type"]]
        assert np.asarray(r["joints_xyz"]).shape == (n, 3) and np.asarray(r["joints_uv"]).shape == (n, 2)
        assert len(r["base_xyz"]) == 3 and r["latency_ms"] > 0
        m = cv2.imread(r["mask"], cv2.IMREAD_GRAYSCALE)
        assert m.shape == (cam.height, cam.width) and set(np.unique(m)) <= {0, 255}
    assert len(list(overlays.glob("*_overlay.png"))) == 2


def test_a_checkpoint_of_another_format_is_one_clear_error(setup, capsys):
    tmp, base, ckpt = setup
    bad = tmp / "old.pt"
    torch.save({"format": 0, "model": {}}, bad)
    rc = predict_main(["--checkpoint", str(bad), str(tmp / "canon")])
    err = capsys.readouterr().err
    assert rc == 1 and "old.pt" in err and "format" in err


class RobotOracle(nn.Module):
    """Stands in for the network: always reports one posed UR5 (base and six joints), type ur5."""

    def __init__(self, base: torch.Tensor, joints: torch.Tensor, type_index: int):
        super().__init__()
        self.b, self.j, self.k = base.float(), joints.float(), type_index

    def forward(self, x):
        n = x.shape[0]
        joints = torch.zeros(n, 7, 3)
        joints[:, :6] = self.j
        logits = torch.full((n, 5), -5.0)
        logits[:, self.k] = 5.0
        return {"joints": joints, "base": self.b.expand(n, 3).clone(), "type_logits": logits,
                "mask_logits": torch.full((n, 1, x.shape[2], x.shape[3]), -10.0)}


def test_fit_gives_the_posed_model_its_joint_angles_and_camera_pose(setup):
    """``--fit``: the predicted type's model posed to the estimate. With an estimate that is a real
    UR5, the fit returns it, with six joint angles and the base's pose in the camera frame."""
    from armpose.robots import get_robot
    from armpose.robots.kinematics import Kinematics, SerialChain
    tmp, base, ckpt = setup
    kin = Kinematics(get_robot("ur5"))
    q = torch.tensor([[0.3, -1.1, 1.4, -0.6, 1.2, 0.4]], dtype=torch.float64)
    pts = SerialChain(kin).positions(q)[0].numpy()
    R = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float)                 # base z axis up in the image
    cam_pts = pts @ R.T + [0.1, 0.3, 2.2]
    oracle = RobotOracle(torch.tensor(cam_pts[0]), torch.tensor(cam_pts[1:]), base["robot_types"].index("ur5"))
    canonical = Camera.from_dict(base["camera"])
    _write_png(tmp / "fit.png", np.zeros((canonical.height, canonical.width, 3), np.uint8))
    plain, fitted = (predict([tmp / "fit.png"], ckpt, model=oracle, fit=fit)[0] for fit in (False, True))
    assert "joint_angles" not in plain and set(fitted) == SCHEMA | {"image", "joint_angles", "camera_T_base"}
    np.testing.assert_allclose(fitted["joints_xyz"], cam_pts[1:], atol=0.01)
    np.testing.assert_allclose(np.asarray(fitted["camera_T_base"])[:3, 3], cam_pts[0], atol=0.01)
    assert len(fitted["joint_angles"]) == 6 and np.asarray(fitted["camera_T_base"]).shape == (4, 4)
    with pytest.raises(SystemExit):                                         # not with --sequence
        predict_main(["--checkpoint", str(ckpt), "--fit", "--sequence", str(tmp / "fit.png")])


@pytest.mark.parametrize("factor", [1, 4])
def test_the_network_sees_a_frame_exactly_as_the_label_stage_makes_training_inputs(setup, factor):
    """Downscaling area-averages, as ``scale_crop_image`` does (no aliasing): the canonical camera
    and a camera ``factor`` times as fine with the same field of view give the training input."""
    tmp, base, ckpt = setup
    canon, net = Camera.from_dict(base["camera"]), network_camera(base)
    cam = Camera(canon.width * factor, canon.height * factor, canon.fx * factor, canon.fy * factor,
                 (canon.cx + 0.5) * factor - 0.5, (canon.cy + 0.5) * factor - 0.5)
    assert cam.scale_crop(net.width, net.height)[0] == net
    noise = np.random.default_rng(factor).integers(0, 256, (cam.height, cam.width, 3), dtype=np.uint8)
    seen = to_network(noise, warp_for(cam, net), net)
    np.testing.assert_array_equal(seen, scale_crop_image(noise, cam, net.width, net.height))


def test_inputs_of_the_same_name_get_their_own_masks_and_overlays(setup, capsys):
    tmp, base, ckpt = setup
    cam = Camera.from_dict(base["camera"])
    rng = np.random.default_rng(3)
    for sub in ("a", "b"):
        (tmp / "same" / sub).mkdir(parents=True)
        _write_png(tmp / "same" / sub / "img.png", rng.integers(0, 255, (cam.height, cam.width, 3), dtype=np.uint8))
    masks, overlays = tmp / "same_masks", tmp / "same_overlays"
    rc = predict_main(["--checkpoint", str(ckpt), "--out", str(tmp / "same.jsonl"), "--masks", str(masks),
                       "--overlays", str(overlays), str(tmp / "same" / "a"), str(tmp / "same" / "b")])
    assert rc == 0, capsys.readouterr().err
    rows = [json.loads(line) for line in (tmp / "same.jsonl").read_text().splitlines()]
    assert [r["mask"].rsplit("/", 1)[1] for r in rows] == ["img_mask.png", "img_2_mask.png"]
    assert sorted(p.name for p in overlays.iterdir()) == ["img_2_overlay.png", "img_overlay.png"]


def test_a_folder_without_images_and_an_unreadable_file_are_errors_that_name_them(setup, capsys, monkeypatch):
    tmp, base, ckpt = setup
    empty = tmp / "empty"
    empty.mkdir()
    (empty / "notes.txt").write_text("no images here")
    cam = Camera.from_dict(base["camera"])
    locked = tmp / "locked.png"
    _write_png(locked, np.zeros((cam.height, cam.width, 3), np.uint8))
    real_fromfile = np.fromfile

    def fromfile(path, *args, **kwargs):
        if str(path) == str(locked):
            raise PermissionError(13, "Permission denied", str(path))
        return real_fromfile(path, *args, **kwargs)

    monkeypatch.setattr(np, "fromfile", fromfile)
    rc = predict_main(["--checkpoint", str(ckpt), "--out", str(tmp / "none.jsonl"), str(empty), str(locked)])
    err = capsys.readouterr().err
    assert rc == 1
    assert f"{empty}: no images in this folder" in err
    assert f"{locked}: cannot read (Permission denied)" in err
    assert (tmp / "none.jsonl").read_text() == ""


@pytest.mark.parametrize("kind", ["gray", "rgba", "16bit", "jpeg"])
def test_grey_alpha_16_bit_and_jpeg_images_are_read_as_rgb_uint8(tmp_path, kind):
    rgb = np.zeros((6, 8, 3), np.uint8)
    rgb[..., 0] = 200                                                   # red
    path = tmp_path / ("img.jpg" if kind == "jpeg" else "img.png")
    data = {"gray": rgb[..., 0], "rgba": np.dstack([rgb[..., ::-1], np.full((6, 8), 7, np.uint8)]),
            "16bit": rgb[..., ::-1].astype(np.uint16) * 257, "jpeg": rgb[..., ::-1]}[kind]
    assert cv2.imwrite(str(path), data)
    img = read_image(path)
    assert img.shape == (6, 8, 3) and img.dtype == np.uint8
    want = [200, 200, 200] if kind == "gray" else [200, 0, 0]
    assert np.abs(img.reshape(-1, 3).astype(int) - want).max() <= 3


def test_a_not_finite_network_output_is_an_error_not_invalid_json(setup, capsys):
    tmp, base, ckpt = setup
    cam = Camera.from_dict(base["camera"])
    net = network_camera(base)
    path = tmp / "nan.png"
    _write_png(path, blob_image(cam, POINTS[0]))
    oracle = BlobOracle(net, float("nan"), 0)
    errors: list = []
    assert predict([path], ckpt, model=oracle, errors=errors) == []
    assert len(errors) == 1 and str(path) in errors[0] and "not finite" in errors[0]
    with pytest.raises(PredictError):
        read_image(tmp / "missing.png")
