"""Augmentation keeps boxes and masks consistent; the letterbox rule is exact."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from slimseg.data.augment import AugmentConfig, masks_to_boxes
from slimseg.data.collate import downsample_masks, make_collate, network_input
from slimseg.data.dataset import ZooDataset
from slimseg.data.sample import Sample
from slimseg.ops.letterbox import boxes_to_frame, letterbox_image, letterbox_params
from slimseg.utils.shipped import shipped_dir


def _random_sample(rng: np.random.Generator, h: int, w: int, index: int) -> Sample:
    """Random rectangles and discs as disjoint visible masks."""
    n = int(rng.integers(1, 6))
    label = np.zeros((h, w), np.int32)
    yy, xx = np.mgrid[:h, :w]
    for k in range(1, n + 1):
        cx, cy = rng.integers(0, w), rng.integers(0, h)
        r = rng.integers(4, max(5, min(h, w) // 3))
        shape = (
            (xx - cx) ** 2 + (yy - cy) ** 2 < r**2
            if k % 2
            else ((abs(xx - cx) < r) & (abs(yy - cy) < r // 2))
        )
        label[shape] = k
    masks = np.stack([(label == k).astype(np.uint8) for k in range(1, n + 1)])
    keep = masks.reshape(n, -1).sum(1) > 0
    masks = masks[keep]
    image = rng.integers(0, 255, (h, w, 3), dtype=np.uint8)
    classes = rng.integers(0, 4, len(masks)).astype(np.int64)
    return Sample(image, masks_to_boxes(masks), classes, masks, image_id=index, path=f"{index}.png")


@pytest.fixture
def base() -> list[Sample]:
    rng = np.random.default_rng(1)
    return [
        _random_sample(rng, int(rng.integers(60, 140)), int(rng.integers(60, 140)), i)
        for i in range(12)
    ]


@pytest.mark.parametrize(
    "h,w,out,expect",
    [
        (480, 640, 320, (0.5, 320, 240, 0, 40)),
        (100, 150, 160, (160 / 150, 160, 107, 0, 26)),
        (33, 17, 64, (64 / 33, 33, 64, 15, 0)),
    ],
)
def test_letterbox_rule(h: int, w: int, out: int, expect: tuple) -> None:
    p = letterbox_params(h, w, out)
    assert (p.scale, p.new_w, p.new_h, p.left, p.top) == pytest.approx(expect)
    img = letterbox_image(np.zeros((h, w, 3), np.uint8), p)
    assert img.shape == (out, out, 3)
    assert (img[: p.top] == 114).all() and (img[p.top + p.new_h :] == 114).all()


def test_boxes_round_trip_through_letterbox() -> None:
    p = letterbox_params(480, 640, 320)
    frame = np.array([[10, 20, 300, 400]], np.float32)
    net = frame * p.scale + np.array([p.left, p.top, p.left, p.top])
    np.testing.assert_allclose(boxes_to_frame(net, p, 480, 640), frame, atol=1e-4)


@pytest.mark.parametrize("mosaic", [0.0, 1.0])
def test_augmented_boxes_enclose_masks_within_1px(base: list[Sample], mosaic: float) -> None:
    ds = ZooDataset(base, 128, AugmentConfig(mosaic=mosaic), seed=3)
    total = 0
    for i in range(len(ds)):
        s = ds[i]
        assert s.image.shape == (128, 128, 3) and s.masks.shape[1:] == (128, 128)
        assert len(s.boxes) == len(s.classes) == len(s.masks)
        np.testing.assert_allclose(s.boxes, masks_to_boxes(s.masks), atol=1)
        assert (s.masks.sum(axis=(1, 2)) >= 4).all()
        total += len(s.masks)
    assert total > 0


def test_augmentation_is_seeded(base: list[Sample]) -> None:
    a = ZooDataset(base, 96, AugmentConfig(), seed=7)
    b = ZooDataset(base, 96, AugmentConfig(), seed=7)
    for i in range(4):
        assert np.array_equal(a[i].image, b[i].image)
        assert np.array_equal(a[i].masks, b[i].masks)


def test_validation_is_letterbox_only(base: list[Sample]) -> None:
    ds = ZooDataset(base, 160)
    s, src = ds[0], base[0]
    p = s.meta["letterbox"]
    assert s.meta["orig_shape"] == src.image.shape[:2]
    assert s.num_instances == src.num_instances
    frame_boxes = boxes_to_frame(s.boxes, p, *src.image.shape[:2])
    np.testing.assert_allclose(frame_boxes, src.boxes, atol=1.5 / p.scale + 1)


def test_collate_layout(base: list[Sample]) -> None:
    ds = ZooDataset(base, 128, AugmentConfig(mosaic=0.0), seed=0)
    samples = [ds[i] for i in range(3)]
    batch = make_collate(4)(samples)
    m = batch["targets"].shape[0]
    assert batch["images"].shape == (3, 3, 128, 128) and batch["images"].dtype == torch.uint8
    assert batch["targets"].shape == (m, 6) and batch["masks"].shape == (m, 32, 32)
    assert set(batch["targets"][:, 0].int().tolist()) <= {0, 1, 2}
    # uint8 CHW copies of the samples' HWC images; the network input is contiguous NCHW
    images = batch["images"]
    assert images.dtype == torch.uint8 and images.is_contiguous()
    for i in range(3):
        assert torch.equal(images[i], torch.from_numpy(samples[i].image).permute(2, 0, 1))
    x = network_input(images)
    assert x.dtype == torch.float32 and x.is_contiguous() and torch.equal(x, images.float() / 255)
    with pytest.raises(TypeError, match="uint8"):
        network_input(x)


def test_downsample_masks_is_block_majority() -> None:
    m = np.zeros((1, 8, 8), np.uint8)
    m[0, :4, :2] = 1  # half of the top-left 4x4 block
    m[0, 4:, 4:] = 1
    assert downsample_masks(m, 4)[0].tolist() == [[1, 0], [0, 1]]


def test_shipped_augment_yaml_is_the_recipe() -> None:

    from slimseg.data.augment import load_augment_config

    path = shipped_dir("data") / "augment.yaml"
    assert load_augment_config(path) == AugmentConfig()


def test_bad_augment_field_is_named(tmp_path) -> None:
    from slimseg.data.augment import load_augment_config
    from slimseg.errors import SlimsegError

    path = tmp_path / "aug.yaml"
    path.write_text("mosaic: 1.0\nflipud: 0.5\n")
    with pytest.raises(SlimsegError, match="flipud"):
        load_augment_config(path)


def test_downsample_masks_equals_the_float_block_mean() -> None:
    rng = np.random.default_rng(3)
    for ratio in (2, 3, 4, 8, 15):
        masks = (rng.random((6, 4 * ratio, 6 * ratio)) < rng.random((6, 1, 1))).astype(np.uint8)
        masks[0], masks[1] = 0, 1
        n, h, w = masks.shape
        blocks = masks.reshape(n, h // ratio, ratio, w // ratio, ratio).astype(np.float32)
        expected = (blocks.mean(axis=(2, 4)) >= 0.5).astype(np.uint8)
        np.testing.assert_array_equal(downsample_masks(masks, ratio), expected)
    with pytest.raises(ValueError, match="too large"):
        downsample_masks(np.zeros((1, 16, 16), np.uint8), 16)


@pytest.mark.parametrize("mosaic", [1.0, 0.0])
def test_decoded_sample_cache_changes_no_sample(base: list[Sample], mosaic: float) -> None:
    cfg = AugmentConfig(mosaic=mosaic)
    plain = ZooDataset(base, 96, cfg, seed=4)
    cached = ZooDataset(base, 96, cfg, seed=4, cache_mib=64)
    for _ in range(3):  # later passes are served from the cache
        for i in range(len(base)):
            a, b = plain[i], cached[i]
            for x, y in ((a.image, b.image), (a.masks, b.masks), (a.boxes, b.boxes)):
                np.testing.assert_array_equal(x, y)
            np.testing.assert_array_equal(a.classes, b.classes)
    assert len(cached._cache) == len(base)
    assert not base[0].image.flags.writeable  # shared arrays cannot be modified in place
    tiny = ZooDataset(list(base), 96, cfg, seed=4, cache_mib=0)
    tiny[0]
    assert not tiny._cache


class _CountingBase(list):
    """A list of samples that records which indices were read (decoded)."""

    def __init__(self, samples: list[Sample]) -> None:
        super().__init__(samples)
        self.reads: list[int] = []

    def __getitem__(self, index):
        self.reads.append(index)
        return super().__getitem__(index)


def test_mosaic_partners_come_from_the_recent_buffer() -> None:
    rng = np.random.default_rng(0)
    base = _CountingBase([_random_sample(rng, 48, 64, i) for i in range(40)])
    ds = ZooDataset(base, 64, AugmentConfig(mosaic=1.0), seed=2, mosaic_buffer=8)
    order = list(rng.permutation(len(base)))
    seen: list[tuple[str, ...]] = []
    for step, i in enumerate(order):
        before = len(base.reads)
        partners = ds[int(i)].meta["mosaic"]
        seen.append(tuple(partners))
        assert partners[0] == f"{i}.png"
        if step >= 10:  # full after 2 or 3 samples; 8 later ones fill it with primaries only
            assert len(base.reads) - before <= 1
            # the 8 most recently requested primaries (each decoded or refreshed then)
            window = {f"{j}.png" for j in order[step - 7 : step + 1]}
            assert set(partners) <= window, (step, partners, window)
    # one decode per sample once full, instead of four: 40 samples plus a few filling extras
    assert len(base.reads) <= len(base) + 3 * 8
    assert len(set(seen)) == len(seen)


def test_reseed_empties_the_buffer_so_an_epoch_depends_only_on_its_seed(
    base: list[Sample],
) -> None:
    a = ZooDataset(base, 96, AugmentConfig(), seed=0, mosaic_buffer=4)
    b = ZooDataset(base, 96, AugmentConfig(), seed=0, mosaic_buffer=4)
    for i in range(len(base)):  # a has a full buffer from "epoch 0", b has never run
        a[i]
    a.reseed(11)
    b.reseed(11)
    for i in reversed(range(len(base))):
        x, y = a[i], b[i]
        assert x.meta["mosaic"] == y.meta["mosaic"]
        assert np.array_equal(x.image, y.image) and np.array_equal(x.masks, y.masks)


@pytest.mark.parametrize("n", [0, 1, 7, 8, 9, 33])
def test_bit_packed_masks_transform_exactly_like_single_masks(n: int) -> None:
    from slimseg.data.augment import build_transform, pack_masks, unpack_masks

    rng = np.random.default_rng(n)
    transform = build_transform(AugmentConfig(), 96, train=True)
    for trial in range(4):
        h, w = int(rng.integers(40, 150)), int(rng.integers(40, 150))
        image = rng.integers(0, 255, (h, w, 3), dtype=np.uint8)
        masks = (rng.random((n, h, w)) < rng.random((n, 1, 1))).astype(np.uint8)
        assert np.array_equal(unpack_masks(pack_masks(masks), n), masks)
        transform.set_random_seed(trial)
        one_by_one = transform(image=image, masks=list(masks) or [np.zeros((h, w), np.uint8)])
        transform.set_random_seed(trial)
        packed = transform(image=image, mask=pack_masks(masks))
        assert np.array_equal(packed["image"], one_by_one["image"])
        expected = np.asarray(one_by_one["masks"], np.uint8)[:n]
        assert np.array_equal(unpack_masks(packed["mask"], n), expected.reshape(n, 96, 96))
