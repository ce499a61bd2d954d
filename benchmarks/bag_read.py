"""Reading a sequence from a ROS bag vs from a TUM folder: frames per second and peak memory,
for a recording of 300 and of 1,200 frames (memory must stay flat as the bag grows).

The same synthetic 640x480 frames (a gradient with a moving disc, depth a tilted plane with
holes) are written as a TUM folder and, with ``slimseg data tum2bag``'s writer, as a ROS 1
bag, a rosbag2 folder (SQLite and MCAP) and a bare MCAP file (raw ``rgb8`` + ``16UC1``, and
PNG + ``compressedDepth``), and as an MCAP of Foxglove protobuf schemas (``RawImage`` ``rgb8`` +
``16UC1``, ``CameraCalibration``; slimseg's Foxglove writer; zstd chunks as the Foxglove SDK
writes them, and without). Each is then read in a fresh
process through ``slimseg.data.sequence_source.open_sequence`` (what every command uses), every
frame ``load``-ed in order; the table gives the opening time, frames per second, the resident
memory after the imports (``import slimseg`` loads torch) and the most it grew above that
while opening and reading (resident memory sampled after every frame).

    python benchmarks/bag_read.py --work /tmp/bag-bench [--frames 300 1200] [--size 640 480] \
        [--kinds 'bare .mcap raw' 'Foxglove protobuf .mcap raw']

Needs the ``[ros]`` extra. The files are kept in ``--work`` (several GB for raw bags of 1,200
frames at 640x480); a second run reuses them.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

KINDS = {  # name → (output name, storage, colour, depth)
    "TUM folder": ("tum", None, None, None),
    "ROS 1 .bag raw": ("raw.bag", None, "rgb8", "16UC1"),
    "rosbag2 SQLite raw": ("sqlite_raw", "sqlite3", "rgb8", "16UC1"),
    "rosbag2 MCAP raw": ("mcap_raw", "mcap", "rgb8", "16UC1"),
    "bare .mcap raw": ("raw.mcap", None, "rgb8", "16UC1"),
    "bare .mcap PNG+compressedDepth": ("png.mcap", None, "png", "compressedDepth"),
    "Foxglove protobuf .mcap raw": ("foxglove_raw.mcap", "foxglove", "rgb8", "16UC1"),
    "Foxglove .mcap raw, no zstd": ("foxglove_plain.mcap", "foxglove-plain", "rgb8", "16UC1"),
}


def _rss_mb() -> float:
    """Resident memory of this process now (MiB, from ``/proc/self/statm``)."""
    pages = int(Path("/proc/self/statm").read_text().split()[1])
    return pages * resource.getpagesize() / 2**20


def write_folder(folder: Path, frames: int, size: tuple[int, int]) -> None:
    """A TUM folder of ``frames`` synthetic frames at 30 Hz (depth 5 ms after colour)."""
    from slimseg.utils.atomic import write_png, write_text, write_yaml

    w, h = size
    yy, xx = np.mgrid[:h, :w].astype(np.float32)
    base = np.stack([xx / w * 255, yy / h * 255, np.full_like(xx, 128)], -1)
    plane = 1.0 + 2.0 * xx / w + 0.5 * yy / h  # metres
    rgb_lines, depth_lines = [], []
    for i in range(frames):
        t = 1_700_000_000 + i / 30
        cx, cy = (i * 7) % w, h / 2 + h / 4 * np.sin(i / 20)
        disc = (xx - cx) ** 2 + (yy - cy) ** 2 < (h / 8) ** 2
        rgb = base.copy()
        rgb[disc] = (250, 40, 40)
        depth = np.where(disc, 0.8, plane)
        depth[(xx.astype(int) + i) % 97 == 0] = 0  # holes
        name = f"{t:.6f}.png"
        dname = f"{t + 0.005:.6f}.png"
        write_png(folder / "rgb" / name, rgb.astype(np.uint8))
        write_png(folder / "depth" / dname, np.round(depth * 5000).astype(np.uint16))
        rgb_lines.append(f"{t:.6f} rgb/{name}\n")
        depth_lines.append(f"{t + 0.005:.6f} depth/{dname}\n")
    write_yaml(folder / "camera.yaml", {"fx": 525.0, "fy": 525.0, "cx": w / 2 - 0.5,
                                        "cy": h / 2 - 0.5, "depth_scale": 5000.0})  # fmt: skip
    write_text(folder / "depth.txt", "".join(depth_lines))
    write_text(folder / "rgb.txt", "".join(rgb_lines))  # last: its presence marks the folder done


def make(work: Path, frames: int, size: tuple[int, int], kinds: list[str]) -> dict[str, Path]:
    """The ``kinds`` (of :data:`KINDS`) for ``frames`` frames under ``work/<frames>/``."""
    from slimseg.data.bags.from_tum import tum_to_bag

    root = work / str(frames)
    folder = root / "tum"
    if not (folder / "rgb.txt").is_file():
        print(f"writing {frames} frames as a TUM folder ...", flush=True)
        write_folder(folder, frames, size)
    paths = {}
    for kind in kinds:
        name, storage, colour, depth = KINDS[kind]
        paths[kind] = root / name
        if not paths[kind].exists():
            print(f"writing {frames} frames as {kind} ...", flush=True)
            if (storage or "").startswith("foxglove"):
                write_foxglove(folder, paths[kind], compress=storage == "foxglove")
            else:
                tum_to_bag(folder, paths[kind], storage, colour, depth)
    return paths


def write_foxglove(folder: Path, out: Path, compress: bool) -> None:
    """The TUM folder as Foxglove protobuf messages, streamed in time order: ``RawImage`` rgb8
    colour and 16UC1 depth (mm), a ``CameraCalibration`` per colour frame; chunks
    zstd-compressed (the Foxglove SDK's default) or not."""
    from slimseg.data.bags.foxglove_writer import FoxgloveWriter
    from slimseg.data.bags.header import Header, stamp_ns
    from slimseg.data.tum import TumSequence

    seq = TumSequence(folder)
    with FoxgloveWriter(out, compress=compress) as w:
        for i in range(len(seq)):
            rgb, depth_m, t = seq.load(i)
            head = Header(stamp_ns(t), "camera")
            w.write_calibration("/camera/color/camera_info", head, (rgb.shape[1], rgb.shape[0]),
                                seq.camera.pinhole)  # fmt: skip
            w.write_image("/camera/color/image_raw", head, rgb, "rgb8")
            mm = np.round(depth_m * 1000).astype(np.uint16)
            w.write_image("/camera/depth/image_raw", Header(stamp_ns(seq.frames[i][1][0]),
                          "camera"), mm, "16UC1")  # fmt: skip


def read_one(path: Path) -> dict:
    """Open ``path`` and load every frame in order (run in a fresh process)."""
    # rosbags' readers are imported before the baseline for every source alike
    import rosbags.rosbag1
    import rosbags.rosbag2  # noqa: F401

    from slimseg.data.sequence_source import open_sequence

    base = _rss_mb()
    t0 = time.perf_counter()
    with open_sequence(path) as seq:
        t1 = time.perf_counter()
        most = _rss_mb()
        for i in range(len(seq)):
            seq.load(i)
            most = max(most, _rss_mb())
        t2 = time.perf_counter()
    return {
        "frames": len(seq),
        "open_s": t1 - t0,
        "fps": len(seq) / (t2 - t1),
        "base_mb": base,
        "growth_mb": most - base,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--frames", type=int, nargs="+", default=[300, 1200])
    ap.add_argument("--size", type=int, nargs=2, default=[640, 480], metavar=("W", "H"))
    ap.add_argument("--kinds", nargs="+", choices=list(KINDS), default=list(KINDS))
    ap.add_argument("--read", type=Path, help=argparse.SUPPRESS)  # the child process
    args = ap.parse_args()
    if args.read is not None:
        print(json.dumps(read_one(args.read)))
        return
    results: dict[str, dict[int, dict]] = {k: {} for k in args.kinds}
    for n in args.frames:
        for kind, path in make(args.work, n, tuple(args.size), args.kinds).items():
            out = subprocess.run(
                [sys.executable, __file__, "--work", str(args.work), "--read", str(path)],
                check=True, capture_output=True, text=True,
            ).stdout  # fmt: skip
            results[kind][n] = json.loads(out.strip().splitlines()[-1])
    w, h = args.size
    print(f"\nreading {w}x{h} RGB-D frames in order (a fresh process each; MiB resident: after "
          "the imports, and the most it grew while opening and reading)")  # fmt: skip
    head = f"{'source':32}" + "".join(
        f" | {n:>5} fr: open s   fps  base MiB  growth" for n in args.frames
    )
    print(head)
    print("-" * len(head))
    for kind, by_n in results.items():
        cells = "".join(
            f" | {'':9}{r['open_s']:6.2f} {r['fps']:5.0f} {r['base_mb']:9.0f} {r['growth_mb']:7.1f}"
            for r in (by_n[n] for n in args.frames)
        )
        print(f"{kind:32}{cells}")


if __name__ == "__main__":
    main()
