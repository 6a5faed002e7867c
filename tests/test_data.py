"""armpose.data on a tiny random dataset: items, selections, loaders, workers and resuming."""
import logging
import pickle

import numpy as np
import pytest
import torch

from armpose.data import (InfiniteBatches, LabelledFrames, make_loader, robot_indices, split_indices,
                          transfer_set, validation_subset)
from armpose.labels.dataset import load_dataset, write_dataset

H, W, J = 12, 16, 7
AUG = {"brightness": 0.3, "contrast": 0.3, "saturation": 0.3, "noise": 0.05}
# frames per robot class (5 classes); class 4 is short of train frames
COUNTS = [30, 30, 30, 30, 6]


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """A labelled dataset with random content, in the on-disk layout of armpose.labels.dataset."""
    rng = np.random.default_rng(0)
    parts = []
    for k, n in enumerate(COUNTS):
        joints = rng.uniform(-1, 1, (n, J, 3)).astype(np.float32)
        joints[..., 2] += 2
        parts.append({
            "images": rng.integers(0, 256, (n, H, W, 3), dtype=np.uint8),
            "masks": rng.integers(0, 2, (n, H, W), dtype=np.uint8),
            "joints": joints,
            "joint_valid": np.tile(np.arange(J) < (6 if k < 3 else 7), (n, 1)),
            "base": rng.uniform(0.5, 3, (n, 3)).astype(np.float32),
            "distance": rng.uniform(1, 3, n).astype(np.float32),
            "intrinsics": np.tile(np.array([20.0, 20.0, 7.5, 5.5], np.float32), (n, 1)),
            "frame": np.arange(n, dtype=np.int64),
            "robot": np.full(n, k, np.int64),
            "recording": np.full(n, k, np.int64),
            "source": np.zeros(n, np.uint8),
            "split": (rng.uniform(size=n) < 0.3).astype(np.uint8),
        })
    parts[4]["split"][:] = [0, 0, 0, 1, 1, 1]
    out = tmp_path_factory.mktemp("data") / "labels"
    write_dataset(out, parts, {"robot_types": ["ur3", "ur5", "ur10", "iiwa", "panda"], "max_joints": J})
    return out


def batches_equal(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def test_items_have_the_documented_shapes_dtypes_and_ranges(folder):
    arrays, _ = load_dataset(folder)
    rows = np.array([3, 40, 125])
    for augment in (None, AUG):
        ds = LabelledFrames(folder, rows, augment=augment, seed=1)
        assert len(ds) == 3
        item = ds[1]
        expected = {"image": ((3, H, W), torch.float32), "mask": ((H, W), torch.float32),
                    "joints": ((J, 3), torch.float32), "joint_valid": ((J,), torch.bool),
                    "base": ((3,), torch.float32), "robot": ((), torch.int64), "distance": ((), torch.float32),
                    "intrinsics": ((4,), torch.float32), "image_size": ((2,), torch.int64),
                    "index": ((), torch.int64)}
        assert {k: (tuple(v.shape), v.dtype) for k, v in item.items()} == expected
        assert 0 <= item["image"].min() and item["image"].max() <= 1
        assert set(item["mask"].unique().tolist()) <= {0.0, 1.0}
        assert item["index"] == 40 and item["robot"] == arrays["robot"][40]
        np.testing.assert_array_equal(item["joints"].numpy(), arrays["joints"][40])
        np.testing.assert_array_equal(item["joint_valid"].numpy(), arrays["joint_valid"][40])
        np.testing.assert_array_equal(item["mask"].numpy(), arrays["masks"][40])


def test_without_augmentation_the_image_is_the_stored_pixels_over_255(folder):
    arrays, _ = load_dataset(folder)
    ds = LabelledFrames(folder, np.arange(10, 20))
    for i in range(len(ds)):
        expected = arrays["images"][10 + i].transpose(2, 0, 1).astype(np.float32) / 255
        np.testing.assert_array_equal(ds[i]["image"].numpy(), expected)


def test_augmentation_depends_only_on_seed_row_and_epoch(folder):
    ds = LabelledFrames(folder, np.arange(20), augment=AUG, seed=3)
    plain = LabelledFrames(folder, np.arange(20))
    a = ds[5]["image"]
    assert torch.equal(a, LabelledFrames(folder, np.array([0, 5]), augment=AUG, seed=3)[1]["image"])
    assert not torch.equal(a, plain[5]["image"])
    assert not torch.equal(a, LabelledFrames(folder, np.arange(20), augment=AUG, seed=4)[5]["image"])
    ds.set_epoch(1)
    b = ds[5]["image"]
    assert not torch.equal(a, b) and torch.equal(b, ds[(5, 1)]["image"]) and torch.equal(a, ds[(5, 0)]["image"])
    assert torch.equal(ds[5]["mask"], plain[5]["mask"]), "augmentation must not touch the labels"
    with pytest.raises(ValueError, match="unknown augmentation"):
        LabelledFrames(folder, np.arange(3), augment={"rotate": 10})


def test_geometric_augmentation_moves_image_mask_and_labels_together(folder):
    geo = {**AUG, "flip": 1.0, "rotate_deg": 5.0, "roll_deg": 10.0}
    plain, ds = LabelledFrames(folder, np.arange(20)), LabelledFrames(folder, np.arange(20), augment=geo, seed=3)
    a, b = plain[5], ds[5]
    assert not torch.equal(a["mask"], b["mask"])
    assert torch.allclose(torch.linalg.vector_norm(a["joints"], dim=-1), torch.linalg.vector_norm(b["joints"], dim=-1),
                          atol=1e-5), "a camera turn keeps every point's distance"
    assert b["joints"][:, 0] @ a["joints"][:, 0] < 0, "flip 1.0 mirrors x (the principal point is centred)"
    assert torch.equal(a["joint_valid"], b["joint_valid"]) and torch.equal(a["intrinsics"], b["intrinsics"])
    assert torch.equal(b["joints"], ds[(5, 0)]["joints"]) and not torch.equal(b["joints"], ds[(5, 1)]["joints"])


def test_dolly_moves_depth_and_image_size_together(folder):
    """A dolly scales the robot's image about the principal point and moves its depth to
    match: each joint's ray is scaled by s and every depth shifts by the same amount."""
    plain = LabelledFrames(folder, np.arange(20))
    ds = LabelledFrames(folder, np.arange(20), augment={**AUG, "dolly": 0.15}, seed=3)
    for i in (2, 5, 9):
        a, b = plain[i], ds[i]
        valid = a["joint_valid"]
        ja, jb = a["joints"][valid].double(), b["joints"][valid].double()
        shift = jb[:, 2] - ja[:, 2]
        assert torch.allclose(shift, shift[0].expand_as(shift), atol=1e-5)
        scale = (ja[:, 2].mean() / jb[:, 2].mean()).item()   # s = z_ref / (z_ref + d)
        ray_a, ray_b = ja[:, :2] / ja[:, 2:], jb[:, :2] / jb[:, 2:]
        assert torch.allclose(ray_b, ray_a * scale, atol=1e-5)
        assert abs(b["distance"].item() * scale - a["distance"].item()) < 1e-4
    assert torch.equal(ds[5]["joints"], ds[(5, 0)]["joints"]) and not torch.equal(ds[5]["joints"], ds[(5, 1)]["joints"])


def test_pickled_dataset_carries_no_memory_maps(folder):
    ds = LabelledFrames(folder, np.arange(100))
    ds[0]
    blob = pickle.dumps(ds)
    assert len(blob) < 10_000
    assert batches_equal(pickle.loads(blob)[7], ds[7])


def test_split_indices_are_disjoint_complete_and_sorted(folder):
    arrays, index = load_dataset(folder)
    train, test = split_indices((arrays, index), "train"), split_indices(folder, "test")
    assert train.dtype == np.int64 and test.dtype == np.int64
    assert np.intersect1d(train, test).size == 0
    np.testing.assert_array_equal(np.union1d(train, test), np.arange(len(arrays["split"])))
    assert (np.diff(train) > 0).all() and (arrays["split"][train] == 0).all()
    np.testing.assert_array_equal(split_indices(arrays["split"], "test"), test)
    rows = robot_indices(arrays, [1, 3])
    np.testing.assert_array_equal(rows, np.flatnonzero(np.isin(arrays["robot"], [1, 3])))


def test_transfer_set_takes_n_train_frames_per_type(folder, caplog):
    arrays, _ = load_dataset(folder)
    rows = transfer_set(arrays, "train", [0, 2, 3], 8, 11)
    assert rows.dtype == np.int64 and (np.diff(rows) > 0).all()
    assert (arrays["split"][rows] == 0).all()
    assert np.bincount(arrays["robot"][rows], minlength=5).tolist() == [8, 0, 8, 8, 0]
    np.testing.assert_array_equal(rows, transfer_set(arrays, robots=[0, 2, 3], per_type=8, seed=11))
    assert not np.array_equal(rows, transfer_set(arrays, robots=[0, 2, 3], per_type=8, seed=12))
    with caplog.at_level(logging.WARNING, logger="armpose.data"):
        short = transfer_set(folder, "train", robots=[4], per_type=8, seed=11)
    np.testing.assert_array_equal(short, [120, 121, 122])
    assert "only 3 train frames" in caplog.text
    everything = transfer_set(arrays, "train", [1, 4], None, 0)
    np.testing.assert_array_equal(everything, np.flatnonzero((arrays["split"] == 0) & np.isin(arrays["robot"], [1, 4])))


def test_validation_subset_caps_each_type_in_the_test_split(folder):
    arrays, _ = load_dataset(folder)
    rows = validation_subset(arrays, "test", 4, 0)
    assert (arrays["split"][rows] == 1).all()
    counts = np.bincount(arrays["robot"][rows], minlength=5)
    have = np.bincount(arrays["robot"][arrays["split"] == 1], minlength=5)
    assert counts.tolist() == np.minimum(have, 4).tolist()
    np.testing.assert_array_equal(rows, validation_subset(arrays, max_per_type=4, seed=0))


def epochs(loader, n):
    out = []
    for epoch in range(n):
        loader.sampler.set_epoch(epoch)
        out.append(list(loader))
    return out


def test_workers_give_the_same_batches_as_the_main_process(folder):
    ds = LabelledFrames(folder, np.arange(0, 126, 3), augment=AUG, seed=5)
    serial = epochs(make_loader(ds, 8, shuffle=True, seed=9, num_workers=0, drop_last=True), 2)
    ds[0]  # memory maps opened in the parent before forking
    parallel = epochs(make_loader(ds, 8, shuffle=True, seed=9, num_workers=2, drop_last=True), 2)
    assert [len(e) for e in serial] == [5, 5]
    assert all(batches_equal(a, b) for e, f in zip(serial, parallel) for a, b in zip(e, f))
    assert not torch.equal(serial[0][0]["index"], serial[1][0]["index"]), "epochs share one order"
    flat = [b for e in serial for b in e]
    resumed = InfiniteBatches(make_loader(ds, 8, shuffle=True, seed=9, num_workers=2, drop_last=True), start_step=3)
    assert all(batches_equal(next(resumed), flat[s]) for s in range(3, 10))


@pytest.mark.slow
def test_spawned_worker_gives_the_same_batches(folder):
    """A spawned worker gets the dataset pickled: it must reopen the arrays itself (~4 s: it imports torch)."""
    ds = LabelledFrames(folder, np.arange(0, 126, 3), augment=AUG, seed=5)
    serial = epochs(make_loader(ds, 8, shuffle=True, seed=9, num_workers=0, drop_last=True), 2)
    ds[0]
    spawned = epochs(make_loader(ds, 8, shuffle=True, seed=9, num_workers=1, drop_last=True,
                                 multiprocessing_context="spawn"), 2)
    assert all(batches_equal(a, b) for e, f in zip(serial, spawned) for a, b in zip(e, f))


@pytest.mark.parametrize("drop_last", [True, False])
def test_infinite_batches_resume_at_any_step(folder, drop_last):
    ds = LabelledFrames(folder, np.arange(0, 126, 5), augment=AUG, seed=2)  # 26 frames

    def loader():
        return make_loader(ds, 4, shuffle=True, seed=7, num_workers=0, drop_last=drop_last)

    per_epoch = 6 if drop_last else 7
    def take(batches, n):
        out = []
        for _ in range(n):
            step = batches.step
            out.append((step, next(batches)))
            assert (batches.step, batches.epoch) == (step + 1, step // per_epoch)
        return out

    run = [b for _, b in take(InfiniteBatches(loader()), 4 * per_epoch)]
    seen = torch.cat([b["index"] for b in run[:per_epoch]])
    assert len(seen) == (24 if drop_last else 26) and len(set(seen.tolist())) == len(seen)
    for k in (0, 4, per_epoch, 2 * per_epoch + 3):
        for s, b in take(InfiniteBatches(loader(), start_step=k), per_epoch + 1):
            assert batches_equal(b, run[s]), f"resumed at {k}, step {s}"


def test_distributed_sampler_with_one_process(folder, tmp_path):
    import torch.distributed as dist
    dist.init_process_group("gloo", init_method=f"file://{tmp_path / 'pg'}", rank=0, world_size=1)
    try:
        ds = LabelledFrames(folder, np.arange(20))
        loader = make_loader(ds, 5, shuffle=True, seed=1, num_workers=0, drop_last=False, distributed=True)
        assert type(loader.sampler.sampler).__name__ == "DistributedSampler"
        e0, e1 = [torch.cat([b["index"] for b in e]) for e in epochs(loader, 2)]
        assert sorted(e0.tolist()) == list(range(20)) and not torch.equal(e0, e1)
        batches = InfiniteBatches(loader, start_step=5)
        batch = next(batches)
        assert (batches.step, batches.epoch) == (6, 1) and torch.equal(batch["index"], e1[5:10])
        plain = make_loader(torch.utils.data.Subset(ds, range(10)), 5, shuffle=False, seed=1, num_workers=0,
                            drop_last=False, distributed=True)
        assert [b["index"].tolist() for b in plain] == [[0, 1, 2, 3, 4], [5, 6, 7, 8, 9]]
    finally:
        dist.destroy_process_group()


def test_foreground_fraction_is_the_mean_mask_share(folder):
    from armpose.data import foreground_fraction
    arrays, _ = load_dataset(folder)
    rows = np.arange(10)
    expected = np.mean([arrays["masks"][r].mean() for r in rows])
    assert foreground_fraction(arrays, rows) == pytest.approx(expected)
    assert foreground_fraction(arrays, np.zeros(0, np.int64)) == 0.5
