"""The paper's Table II beside a sweep's rows: which arms have a paper row, the side-by-side
table, the changes against each table's baseline and the notes on why they differ."""

from __future__ import annotations

import re

from slimseg.ablate.mdtable import pct, pts, rel, table
from slimseg.eval.paper import TABLE2, TABLE2_IMGSZ, TABLE2_NUM_CLASSES, PaperRow

NOTES = """\
How to read the two tables:
- Scale and recipe differ: the paper trained the s-scale variants for 500 epochs on COCO-20 at
  640 px; a synthetic CPU sweep trains n-scale variants for minutes. Compare the *changes
  against each table's baseline row*, not the absolute mAP.
- GFLOPs: ours are 2 x multiply-adds counted by torch's FlopCounterMode in eval mode. The
  paper's tool (thop through the reference code) also counts 4 operations per BatchNorm
  output and overcounts ConvTranspose; "GFLOPs paper conv." applies that convention, and at
  s scale, nc 20, 640 px it reproduces the paper's column to within 0.06.
- The unused conv: the published VoVGSCSP defines a 3x3 conv it never calls. The paper
  counted it in params and gradients of the -gs rows; "params paper conv." adds it, the
  main params column does not (it cannot train: it gets no gradient).
- The -rep params: the paper lists 12.2 M for -rep but 10.2 M for -gs-rep. Both necks feed
  the head the same channels, so a head change must move both rows by the same amount; the
  pair cannot both hold. Our shared RepConv head removes the same parameters in both rows and
  its GFLOPs match the paper's.
"""


def paper_key(variant: str) -> str | None:
    """The Table II row a variant corresponds to (scale ignored), if any."""
    key = re.sub(r"^yolov8[nsmlx]-", "yolov8s-", variant)
    return key if key in TABLE2 else None


def paper_section(rows: list[dict], paired: list[tuple[dict, PaperRow]]) -> list[str]:
    """The paper's Table II beside ``rows`` (arm summaries; ``paired``: those with a paper
    row), then every row's change against its own table's baseline."""
    base = next((r for r in rows if paper_key(r["variant"]) == "yolov8s-seg"), None)
    paper_base = TABLE2["yolov8s-seg"]
    out = [
        f"## The paper's Table II beside ours (paper: s scale, COCO-20, nc "
        f"{TABLE2_NUM_CLASSES}, {TABLE2_IMGSZ} px, 500 epochs)",
        "",
        table(
            [
                "Model (ours → paper row)",
                "box ours",
                "box paper",
                "seg ours",
                "seg paper",
                "GFLOPs paper conv. ours",
                "GFLOPs paper",
                "Params paper conv. M ours",
                "Params M paper",
            ],
            [
                [
                    f"{r['variant']} → {paper_key(r['variant'])}",
                    pct(r["box_map50_95"]),
                    f"{p.box_map:.1f}",
                    pct(r["seg_map50_95"]),
                    f"{p.seg_map:.1f}",
                    f"{r['gflops_paper']:.2f}",
                    f"{p.gflops:.1f}",
                    f"{r['params_paper'] / 1e6:.2f}",
                    f"{p.params_m:.1f}",
                ]
                for r, p in paired
            ],
        ),
    ]
    if base is not None:
        out += [
            "",
            "Changes against each table's own baseline (mAP in points, cost in %):",
            "",
            table(
                [
                    "Model",
                    "Δ box ours",
                    "Δ box paper",
                    "Δ seg ours",
                    "Δ seg paper",
                    "Δ GFLOPs ours",
                    "Δ GFLOPs paper",
                    "Δ params ours",
                    "Δ params paper",
                ],
                [
                    [
                        r["variant"],
                        pts(r["box_map50_95"], base["box_map50_95"]),
                        f"{p.box_map - paper_base.box_map:+.1f}",
                        pts(r["seg_map50_95"], base["seg_map50_95"]),
                        f"{p.seg_map - paper_base.seg_map:+.1f}",
                        rel(r["gflops_paper"], base["gflops_paper"]),
                        rel(p.gflops, paper_base.gflops),
                        rel(r["params_paper"], base["params_paper"]),
                        rel(p.params_m, paper_base.params_m),
                    ]
                    for r, p in paired
                ],
            ),
        ]
    return [*out, "", NOTES]
