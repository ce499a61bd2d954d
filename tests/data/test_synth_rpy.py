"""The ``walking_rpy`` preset (fast roll/pitch/yaw) and the sequences' motion blur.

groundtruth.txt must carry the rotation that was rendered: its poses reproject one frame's
static pixels onto the next (colour and depth), and its angles are the preset's sinusoids.
Motion blur (``--exposure-ms``) is on by default for ``walking_rpy`` only, lowers the image
gradient energy more where the image moves faster, touches only the RGB, and is reproduced by
data.yaml's regenerate comment. Other presets' bytes are pinned by test_synth_identity.py.
"""

from __future__ import annotations

import itertools
import shlex
from pathlib import Path

import cv2
import numpy as np
import pytest

from slimseg.cli.main import main
from slimseg.data.synth import generate, render_sequence_frame
from slimseg.data.synth.blur import WalkerLayer, blur_frame, displacement, line_blur
from slimseg.data.synth.camera import Intrinsics, Pose
from slimseg.data.synth.generate import synth_command
from slimseg.data.synth.presets import PRESETS, default_exposure_ms
from slimseg.data.synth.sequence import placements_at
from slimseg.data.synth.world import FPS, build_world, camera_pose
from slimseg.errors import SlimsegError
from slimseg.utils.manifest import MANIFEST

pytestmark = pytest.mark.filterwarnings("ignore:__array__ implementation:DeprecationWarning")
SIZE = (160, 120)
FRAMES = 20


def _files(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in root.rglob("*") if p.is_file()}


def _quat_to_matrix(q: np.ndarray) -> np.ndarray:
    x, y, z, w = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _groundtruth(seq: Path) -> tuple[np.ndarray, list[np.ndarray]]:
    """Positions ``[N, 3]`` and camera-to-world rotations read from groundtruth.txt."""
    rows = np.loadtxt(seq / "groundtruth.txt", comments="#", ndmin=2)
    return rows[:, 1:4], [_quat_to_matrix(r[4:8]) for r in rows]


@pytest.fixture(scope="module")
def rpy(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("rpy") / "ds"
    generate(out, 0, 0, 64, 0, sequences=1, frames=FRAMES, seq_size=SIZE, progress=False,
             preset="walking_rpy")  # fmt: skip
    return out


def test_rpy_renders_people_and_fast_rotation(rpy: Path) -> None:
    seq = rpy / "sequences" / "seq_000"
    assert len(list((seq / "rgb").glob("*.png"))) == FRAMES
    masks = [cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in (seq / "dynamic").glob("*.png")]
    assert np.mean([m.mean() / 255 > 0.01 for m in masks]) >= 0.8  # people in most frames
    pos, rots = _groundtruth(seq)
    speed = [np.degrees(np.arccos(np.clip((np.trace(a.T @ b) - 1) / 2, -1, 1))) * FPS
             for a, b in itertools.pairwise(rots)]  # fmt: skip
    assert max(speed) > 40.0 and np.mean(speed) > 25.0, speed  # deg/s
    assert np.ptp(pos, 0).max() < 0.1  # at one spot


def test_groundtruth_angles_are_the_presets_sinusoids(rpy: Path) -> None:
    _, rots = _groundtruth(rpy / "sequences" / "seq_000")
    world = build_world(0, 0, FRAMES, *SIZE, preset="walking_rpy")
    assert {"pitch", "roll"} <= set(world.motion)
    for i, r in enumerate(rots):  # R = R_y(yaw) R_x(pitch) R_z(roll)
        got = (np.arctan2(r[0, 2], r[2, 2]), -np.arcsin(r[1, 2]), np.arctan2(r[1, 0], r[1, 1]))
        want = [amp * np.sin(2 * np.pi * f * i / FPS + ph)
                for amp, f, ph in (world.motion[a] for a in ("yaw", "pitch", "roll"))]  # fmt: skip
        np.testing.assert_allclose(got, want, atol=2e-5)
    amp = {a: world.motion[a][0] for a in ("yaw", "pitch", "roll")}
    for axis, (lo, hi) in ((a, PRESETS["walking_rpy"].motion[a][0]) for a in amp):
        assert lo <= amp[axis] <= hi and np.degrees(amp[axis]) >= 10


def test_groundtruth_reprojects_rendered_motion(rpy: Path) -> None:
    """Room pixels of frame i, back-projected with their depth and gt pose i and projected
    with gt pose j, land on the same colour and depth in frame j; a wrong roll does not."""
    pos, rots = _groundtruth(rpy / "sequences" / "seq_000")
    world = build_world(0, 0, FRAMES, *SIZE, preset="walking_rpy", exposure_ms=0)
    k, i, j = world.k, 6, 9
    a, b = render_sequence_frame(world, i).frame, render_sequence_frame(world, j).frame
    vs, us = np.nonzero(a.labels == 0)
    z = a.depth_m[vs, us]
    cam = np.stack([(us - k.cx) / k.fx * z, (vs - k.cy) / k.fy * z, z], 1)

    def error(rot_j: np.ndarray) -> tuple[float, float]:
        pj = ((cam @ rots[i].T + pos[i]) - pos[j]) @ rot_j
        u, v = k.fx * pj[:, 0] / pj[:, 2] + k.cx, k.fy * pj[:, 1] / pj[:, 2] + k.cy
        ui, vi = np.rint(u).astype(int), np.rint(v).astype(int)
        ok = (ui >= 1) & (ui < k.width - 1) & (vi >= 1) & (vi < k.height - 1)
        ok[ok] &= b.labels[vi[ok], ui[ok]] == 0
        assert ok.mean() > 0.5
        got = cv2.remap(b.rgb, u.astype(np.float32)[ok, None], v.astype(np.float32)[ok, None],
                        cv2.INTER_LINEAR)[:, 0].astype(float)  # fmt: skip
        colour = np.abs(got - a.rgb[vs[ok], us[ok]]).mean()
        return colour, float(np.median(np.abs(b.depth_m[vi[ok], ui[ok]] - pj[ok, 2])))

    colour, depth = error(rots[j])
    roll = world.pose(j).roll
    wrong = rots[j] @ _quat_to_matrix(np.array([0, 0, np.sin(-roll), np.cos(-roll)]))
    assert depth < 0.01 and colour < 0.5 * error(wrong)[0] and colour < 0.5 * error(rots[i])[0]


def test_rolled_sprites_turn_with_the_vertical() -> None:
    world = build_world(0, 0, 10, *SIZE, preset="walking_rpy")
    level, rolled = Pose(z=-0.5), Pose(z=-0.5, roll=0.3)
    base = {p.track_id: p.style.params.get("tilt", 0.0) for p in placements_at(world, level, 0.0)}
    turned = placements_at(world, rolled, 0.0)
    assert turned and all(p.track_id in base for p in turned)
    for p in turned:  # world verticals turn by -roll in the image (pitch = 0: no convergence)
        assert p.style.params["tilt"] == pytest.approx(base[p.track_id] - 0.3, abs=1e-9)


def test_walkers_pass_through_the_view_across_seeds() -> None:
    for seed in range(5):
        world = build_world(seed, 0, 90, *SIZE, preset="walking_rpy")
        seen = 0
        for i in range(90):
            ps = placements_at(world, world.pose(i), i / FPS)
            seen += any(p.moving and 0 < p.cx < SIZE[0] and p.size > 20 for p in ps)
        assert seen >= 0.6 * 90, (seed, seen)


def test_exposure_defaults_and_limits() -> None:
    assert default_exposure_ms("walking_rpy") == 20.0
    assert all(default_exposure_ms(n) == 0.0 for n in PRESETS if n != "walking_rpy")
    assert default_exposure_ms(None) == 0.0
    assert build_world(0, 0, 5, *SIZE, preset="walking_rpy").exposure == 0.02
    assert build_world(0, 0, 5, *SIZE, preset="walking_xyz").exposure == 0.0
    for bad in (-1.0, 40.0):
        with pytest.raises(SlimsegError, match="exposure"):
            build_world(0, 0, 5, *SIZE, preset="walking_rpy", exposure_ms=bad)
    pose = camera_pose({"x": (0, 1, 0), "y": (0, 1, 0), "z": (0, 1, 0), "yaw": (0.1, 1, 0)},
                       (0.0, 0.0), 0.3)  # fmt: skip
    assert pose.pitch == pose.roll == 0.0 and pose.yaw_only


def _gradient_energy(rgb: np.ndarray) -> np.ndarray:
    g = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32)
    return cv2.Sobel(g, cv2.CV_32F, 1, 0) ** 2 + cv2.Sobel(g, cv2.CV_32F, 0, 1) ** 2


def test_blur_is_stronger_where_the_image_moves_faster() -> None:
    i = 10
    frames = {
        ms: render_sequence_frame(build_world(0, 0, FRAMES, 320, 240, "walking_rpy", ms), i)
        for ms in (0, 10, 30)
    }
    energy = {ms: _gradient_energy(sf.background_rgb) for ms, sf in frames.items()}
    assert energy[30].mean() < energy[10].mean() < 0.9 * energy[0].mean()
    world = build_world(0, 0, FRAMES, 320, 240, "walking_rpy", 30)
    flow = displacement(world.k, world.exposure_poses(i), frames[0].frame.room_depth_m)
    speed = np.linalg.norm(flow, axis=-1)
    lo, hi = speed <= np.quantile(speed, 0.3), speed >= np.quantile(speed, 0.7)
    ratio = [energy[30][sel].sum() / energy[0][sel].sum() for sel in (lo, hi)]
    assert ratio[1] < ratio[0], ratio
    sharp, blurred = frames[0], frames[30]  # the blur touches the RGB only
    assert np.array_equal(sharp.frame.depth, blurred.frame.depth)
    assert np.array_equal(sharp.dynamic, blurred.dynamic)
    assert np.array_equal(sharp.frame.labels, blurred.frame.labels)


def test_blur_without_motion_is_the_sharp_frame() -> None:
    rng = np.random.default_rng(0)
    src = rng.uniform(0, 255, (30, 40, 4)).astype(np.float32)
    assert np.array_equal(line_blur(src, np.zeros((30, 40, 2), np.float32)), src)
    world = build_world(0, 0, FRAMES, *SIZE, preset="walking_rpy", exposure_ms=0)
    sf = render_sequence_frame(world, 5)
    rgb, bg = sf.frame.rgb, sf.background_rgb
    mask = sf.dynamic > 0
    pose = world.pose(5)
    layer = WalkerLayer(mask, 2.0, (0.0, 0.0))
    bg_b, full, footprint = blur_frame(
        world.k, (pose, pose, pose), rgb, bg, sf.frame.depth_m, [layer]
    )
    assert np.array_equal(bg_b, bg) and np.array_equal(full, rgb)
    assert np.array_equal(footprint, mask)


def test_walker_streak_leaves_its_mask() -> None:
    h, w = 60, 80
    rgb = np.zeros((h, w, 3), np.uint8)
    mask = np.zeros((h, w), bool)
    mask[20:40, 30:40] = True
    rgb[mask] = 200
    pose = Pose(z=-1.0)
    layer = WalkerLayer(mask, 2.0, (12.0, 0.0))  # 12 px to the right during the exposure
    k = Intrinsics.tum(w, h)
    _, full, footprint = blur_frame(k, (pose, pose, pose), rgb, np.zeros_like(rgb),
                                    np.full((h, w), 5.0, np.float32), [layer])  # fmt: skip
    row = full[30, :, 0]
    assert footprint[30, 25] and footprint[30, 44] and not footprint[30, 20]
    assert 0 < row[26] < row[35] and 0 < row[43] < row[35]  # ramps in and out, both sides
    assert full[:, :, 0].sum() == pytest.approx(rgb[:, :, 0].astype(float).sum(), rel=1e-3)


def test_same_arguments_same_bytes_and_exposure_only_changes_rgb(rpy: Path, tmp_path: Path) -> None:
    again, off = tmp_path / "again", tmp_path / "off"
    common = dict(sequences=1, frames=FRAMES, seq_size=SIZE, progress=False, preset="walking_rpy")
    generate(again, 0, 0, 64, 0, **common)
    generate(off, 0, 0, 64, 0, exposure_ms=0.0, **common)
    first = _files(rpy)
    assert _files(again) == first
    sharp = _files(off)
    for name, data in first.items():
        same = not name.startswith(("sequences/seq_000/rgb/", "sequences/seq_000/background/rgb/"))
        # the manifest records every file's hash, so it changes with the rgb files it lists
        assert (sharp[name] == data) == same or name in ("data.yaml", MANIFEST), name
    assert "--exposure-ms 0" in (off / "data.yaml").read_text().splitlines()[1]
    assert "--exposure-ms" not in (rpy / "data.yaml").read_text()


def test_synth_command_names_a_non_default_exposure() -> None:
    cmd = synth_command(0, 0, 64, 0, 1, 10, (160, 120), "walking_xyz", exposure_ms=12.5)
    assert cmd.endswith("--preset walking_xyz --exposure-ms 12.5")
    assert "--exposure-ms" not in synth_command(0, 0, 64, 0, 1, 10, (160, 120), "walking_rpy",
                                                exposure_ms=20.0)  # fmt: skip
    assert "--exposure-ms" not in synth_command(0, 0, 64, 0, 1, 10, exposure_ms=0.0)
    assert synth_command(0, 0, 64, 0, 1, 10, exposure_ms=1 / 3).endswith(f"--exposure-ms {1 / 3!r}")
    assert "--exposure-ms" not in synth_command(4, 2, 64, 0, exposure_ms=5.0)  # no sequences


def test_regenerate_comment_reproduces_a_blurred_set(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    argv = ["data", "synth", "--out", "a", "--train", "0", "--val", "0", "--sequences", "1",
            "--frames", "6", "--seq-size", "96", "64", "--preset", "walking_xyz",
            "--exposure-ms", "12.5", "--quiet"]  # fmt: skip
    assert main(argv) == 0
    comment = Path("a/data.yaml").read_text().splitlines()[1]
    regen = shlex.split(comment.removeprefix("# ").replace("<dir>", "b"))
    assert regen[:3] == ["slimseg", "data", "synth"] and "--exposure-ms" in regen
    assert main([*regen[1:], "--quiet"]) == 0
    assert _files(Path("b")) == _files(Path("a"))
    assert main([*argv[:-3], "--exposure-ms", "40", "--quiet"]) != 0
    assert "--exposure-ms 40" in capsys.readouterr().err
