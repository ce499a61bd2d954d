"""What a robot pays for slimseg, side by side in one run: several installs (e.g. today's full
install and the core ``pip install slimseg``), each a Python interpreter (and optionally a
source tree put first on its path).

Per install: site-packages size and package count, which of torch, torchvision, Lightning,
tensorboard and albumentations it holds; ``import slimseg; slimseg.Masker`` and
``slimseg --help`` wall time and peak resident memory (``/usr/bin/time -v``, a fresh process
each, best of ``--repeat``); a ``Masker`` loop over a sequence's frames (peak memory, ms per
frame by part: model, post-processing, features, track, logic); ``slimseg dynamic`` on the
sequence (peak memory, wall time, a digest of the masks it writes).

    python benchmarks/install_footprint.py --model M.onnx --sequence SEQ \\
        --install today=.venv/bin/python:/path/to/old/checkout --install core=/venv-core/bin/python
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import subprocess
import tempfile
from pathlib import Path

LOOP = """
import json, sys, time
import slimseg
from slimseg.data.tum import TumSequence
from slimseg.deploy.predictor import Predictor
run, last = Predictor.predict, {}
def predict(self, *a, **k):  # the post-processing's share of the model's time
    out = run(self, *a, **k)
    last.update(out.timings)
    return out
Predictor.predict = predict
model, folder, frames, track = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4] == "1"
parts = {"model": [], "postprocess": [], "features": [], "track": [], "logic": [], "latency": []}
with TumSequence(folder) as seq, slimseg.Masker.from_onnx(model, threads=1, track=track) as m:
    for i in range(min(frames, len(seq))):
        rgb, depth, stamp = seq.load(i)
        f = m.step(rgb, depth, stamp)
        if i == 0:
            continue  # the first frame pays one-off costs
        post = last.get("postprocess", 0.0)
        for k in parts:
            parts[k].append(post if k == "postprocess" else getattr(f.timing, k))
print(json.dumps({k: sum(v) / max(len(v), 1) for k, v in parts.items()}))
"""


def timed(cmd: list[str], env: dict[str, str]) -> tuple[float, float, str]:
    """Wall seconds, peak resident MB and stdout of ``cmd`` under ``/usr/bin/time -v``."""
    proc = subprocess.run(
        ["/usr/bin/time", "-v", *cmd], capture_output=True, text=True, env=env, timeout=3600
    )
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{proc.stderr[-2000:]}")
    rss = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", proc.stderr).group(1))
    m = re.search(
        r"Elapsed \(wall clock\) time \(h:mm:ss or m:ss\): (?:(\d+):)?(\d+):([\d.]+)", proc.stderr
    )
    wall = int(m.group(1) or 0) * 3600 + int(m.group(2)) * 60 + float(m.group(3))
    return wall, rss / 1024, proc.stdout


def site_packages(python: str, env: dict[str, str]) -> tuple[float, int]:
    """MB on disk and the number of distributions of the interpreter's site-packages."""
    code = "import sysconfig; print(sysconfig.get_paths()['purelib'])"
    path = Path(subprocess.run([python, "-c", code], capture_output=True, text=True, env=env,
                               check=True).stdout.strip())  # fmt: skip
    size = sum(f.stat().st_size for f in path.rglob("*") if f.is_file() and not f.is_symlink())
    return size / 2**20, len(list(path.glob("*.dist-info")))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--install", action="append", required=True,
                    help="NAME=PYTHON[:SOURCE_TREE] (repeat)")  # fmt: skip
    ap.add_argument("--model", required=True)
    ap.add_argument("--sequence", required=True)
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    rows = {}
    for spec in args.install:
        name, rest = spec.split("=", 1)
        python, _, tree = rest.partition(":")
        env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
        if tree:
            env["PYTHONPATH"] = tree
        row: dict[str, object] = {}
        row["site_mb"], row["packages"] = site_packages(python, env)
        find = "import importlib.util as u; print(','.join(m for m in " \
            "('torch', 'torchvision', 'lightning', 'tensorboard', 'albumentations') " \
            "if u.find_spec(m)))"  # fmt: skip
        row["train_stack"] = subprocess.run([python, "-c", find], capture_output=True, text=True,
                                            env=env, check=True).stdout.strip() or "-"  # fmt: skip
        probe = "import sys, slimseg; getattr(slimseg, 'Masker', None); print(','.join(" \
            "m for m in ('torch', 'torchvision', 'lightning', 'pycocotools', 'scipy') " \
            "if m in sys.modules))"  # fmt: skip
        best = min(timed([python, "-c", probe], env)[:2] for _ in range(args.repeat))
        row["import_s"], row["import_mb"] = best
        row["import_loads"] = timed([python, "-c", probe], env)[2].strip() or "-"
        best = min(timed([python, "-m", "slimseg", "--help"], env)[:2] for _ in range(args.repeat))
        row["help_s"], row["help_mb"] = best
        for track in (False, True):
            _, mb, out = timed(
                [python, "-c", LOOP, args.model, args.sequence, str(args.frames), str(int(track))],
                env,
            )
            row[f"loop{'_track' if track else ''}_mb"] = mb
            row[f"loop{'_track' if track else ''}_ms"] = json.loads(out.splitlines()[-1])
        with tempfile.TemporaryDirectory() as tmp:
            out_dir = Path(tmp) / "out"
            cmd = [python, "-m", "slimseg", "dynamic", "--model", args.model, "--sequence",
                   args.sequence, "--out", str(out_dir), "--threads", "1", "--quiet"]  # fmt: skip
            row["dynamic_s"], row["dynamic_mb"], _ = timed(cmd, env)
            digest = hashlib.sha256()
            for f in sorted((out_dir / "masks").iterdir()):
                digest.update(f.read_bytes())
            row["dynamic_masks"] = digest.hexdigest()[:16]
        rows[name] = row
        print(name, json.dumps(row), flush=True)
    print()
    names = list(rows)
    print("| measure | " + " | ".join(names) + " |")
    print("|---|" + "---:|" * len(names))
    keys = [k for k in rows[names[0]] if not k.startswith("loop")]
    for k in keys:
        vals = [rows[n][k] for n in names]
        print(f"| {k} | " + " | ".join(f"{v:.2f}" if isinstance(v, float) else str(v)
                                      for v in vals) + " |")  # fmt: skip
    for loop in ("loop", "loop_track"):
        print(
            f"| {loop} peak MB | "
            + " | ".join(f"{rows[n][f'{loop}_mb']:.0f}" for n in names)
            + " |"
        )
        for part in rows[names[0]][f"{loop}_ms"]:
            vals = " | ".join(f"{rows[n][f'{loop}_ms'][part]:.1f}" for n in names)
            print(f"| {loop} {part} ms/frame | {vals} |")


if __name__ == "__main__":
    main()
