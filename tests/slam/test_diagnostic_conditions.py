"""slam-eval's diagnostic conditions: a run's masks at perfect precision (within the ground
truth) and at perfect recall (plus the ground truth), by hand on a generated sequence."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from slimseg.cli.slam_eval import _restore_list, parse_modes
from slimseg.data.synth import generate
from slimseg.data.tum import TumSequence, mask_name
from slimseg.dynamic.seg_box import dilate
from slimseg.errors import SlimsegError
from slimseg.slam.conditions import Condition, condition_frames
from slimseg.slam.diagnostic import DIAGNOSTIC, NEAR_TRUTH_PX


@pytest.fixture(scope="module")
def seq(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("diag") / "data"
    generate(out, 1, 1, 64, 0, sequences=1, frames=4, seq_size=(160, 120), progress=False,
             preset="walking_xyz")  # fmt: skip
    return out / "sequences" / "seq_000"


def test_masks_within_and_plus_the_ground_truth(seq: Path, tmp_path: Path) -> None:
    tum = TumSequence(seq)
    masks = tmp_path / "masks"
    masks.mkdir()
    left = np.zeros((120, 160), np.uint8)
    left[:, :80] = 255  # the left half "dynamic" in every frame: half right, half wrong
    for (stamp, _), _ in tum.frames:
        cv2.imwrite(str(masks / mask_name(stamp)), left)
    truth = seq / "dynamic"
    within = condition_frames(tum, Condition("w", "masked", masks=masks, truth=truth,
                                             combine="within"))  # fmt: skip
    plus = condition_frames(tum, Condition("p", "masked", masks=masks, truth=truth,
                                           combine="plus"))  # fmt: skip
    plain = condition_frames(tum, Condition("m", "masked", masks=masks))
    seen = 0
    for i, ((stamp, _), _) in enumerate(tum.frames):
        gt = cv2.imread(str(truth / mask_name(stamp)), cv2.IMREAD_GRAYSCALE) > 0
        near = dilate(gt, NEAR_TRUTH_PX).astype(bool)
        removed = {name: f[i].static == 0 for name, f in
                   (("within", within), ("plus", plus), ("plain", plain))}  # fmt: skip
        assert np.array_equal(removed["plain"], left > 0)
        assert np.array_equal(removed["within"], (left > 0) & near)
        assert np.array_equal(removed["plus"], (left > 0) | gt)
        seen += int(gt.any())
    assert seen  # the sequence has walkers to combine with
    short = tmp_path / "short"  # a ground-truth mask missing: one line naming it
    short.mkdir()
    first = mask_name(tum.frames[0][0][0])
    (short / first).write_bytes((truth / first).read_bytes())
    with pytest.raises(SlimsegError, match=r"missing or unreadable ground-truth mask .*short"):
        condition_frames(tum, Condition("w", "masked", masks=masks, truth=short, combine="plus"))


def test_diagnostic_modes_need_masks_and_are_not_restored() -> None:
    assert set(DIAGNOSTIC) == {"masks-within-gt", "masks-plus-gt"}
    names = parse_modes("raw,gt,masks,masks-within-gt,masks-plus-gt", False, True)
    assert names[-2:] == ["masks-within-gt", "masks-plus-gt"]
    with pytest.raises(SlimsegError, match="masks-within-gt needs --masks DIR"):
        parse_modes("raw,masks-within-gt", False, False)
    assert _restore_list("all", names) == ("gt", "masks")
    with pytest.raises(SlimsegError, match="not among the masked"):
        _restore_list("masks-plus-gt", names)
