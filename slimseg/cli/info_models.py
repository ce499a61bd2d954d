"""The model half of ``slimseg info`` (the training stack's): params, gradients and GFLOPs of one
variant or of the whole zoo, as tables or JSON."""

from __future__ import annotations

import argparse
import json

from torch import nn

from slimseg.eval.complexity import Complexity, count_params, measure
from slimseg.eval.paper import TABLE2, TABLE2_IMGSZ, TABLE2_NUM_CLASSES
from slimseg.models.registry import build_model, list_models
from slimseg.utils.table import format_table
from slimseg.utils.text import printable


def _measure(name: str, nc: int | None, imgsz: int, fused: bool) -> tuple[nn.Module, Complexity]:
    model = build_model(name, num_classes=nc, fused=fused)
    return model, measure(model, imgsz)


def _components(model: nn.Module) -> list[tuple[str, int]]:
    return [(name, count_params(child)[0]) for name, child in model.named_children()]


def report_models(args: argparse.Namespace) -> int:
    """Print ``args.model``'s (``all``: every variant's) size and cost; exit status 0."""
    names = list_models() if args.model == "all" else [args.model]
    results = []
    for name in names:
        model, c = _measure(name, args.nc, args.imgsz, args.fused)
        results.append((model, c))
    if args.json:
        out = [
            {"model": m.spec.name, "num_classes": m.spec.num_classes, "spec_hash": m.spec.hash}
            | c.to_dict()
            | {"components": dict(_components(m))}
            for m, c in results
        ]
        print(json.dumps(out if args.model == "all" else out[0], indent=2))
        return 0
    if args.model != "all":
        _print_one(*results[0])
        return 0
    _print_zoo(results, args)
    return 0


def _print_one(model: nn.Module, c: Complexity) -> None:
    spec = model.spec
    print(printable(f"{spec.name}: {spec.description}"))  # a user's spec file
    print(f"  classes {spec.num_classes}, input {c.imgsz[0]}x{c.imgsz[1]}, spec hash {spec.hash}")
    rows = [
        ("params", c.params),
        ("gradients (requires_grad)", c.gradients),
        ("params, paper-comparable (+ unused conv)", c.params_paper),
        ("fused params", c.fused_params),
        ("GFLOPs (ours)", c.gflops),
        ("GFLOPs (paper convention)", c.gflops_paper),
        ("fused GFLOPs (ours)", c.fused_gflops),
    ]
    print(format_table(["quantity", "value"], rows))
    print()
    print(format_table(["component", "params"], _components(model)))


def _print_zoo(results: list[tuple[nn.Module, Complexity]], args: argparse.Namespace) -> None:
    headers = [
        "model",
        "params",
        "gradients",
        "params (paper-comp.)",
        "fused params",
        "GFLOPs",
        "GFLOPs (paper conv.)",
        "fused GFLOPs",
    ]
    rows = [
        [m.spec.name, c.params, c.gradients, c.params_paper, c.fused_params]
        + [c.gflops, c.gflops_paper, c.fused_gflops]
        for m, c in results
    ]
    nc = results[0][0].spec.num_classes if args.nc is not None else "spec default"
    print(f"slimseg model zoo: {len(rows)} variants, nc={nc}, {args.imgsz}x{args.imgsz}, batch 1")
    print(format_table(headers, rows))
    print(
        "\nGFLOPs = 2 x multiply-adds (FlopCounterMode, eval). Paper convention adds the thop "
        "ConvTranspose overcount and 4 ops per BatchNorm output element.\n"
        "params (paper-comp.) adds the original VoVGSCSP's unused 3x3 conv (-gs variants)."
    )
    if args.nc != TABLE2_NUM_CLASSES or args.imgsz != TABLE2_IMGSZ:
        print(
            f"\n(run with --nc {TABLE2_NUM_CLASSES} --imgsz {TABLE2_IMGSZ} to compare with the "
            "paper's Table II)"
        )
        return
    by_name = {m.spec.name: c for m, c in results}
    cmp_rows = []
    for name, paper in TABLE2.items():
        if name not in by_name:
            continue
        c = by_name[name]
        cmp_rows.append(
            [name, round(c.params_paper / 1e6, 2), paper.params_m]
            + [round((c.gradients + c.dead_params) / 1e6, 2), paper.gradients_m]
            + [
                round(c.gflops_paper, 2),
                paper.gflops,
                round(c.gflops_paper - paper.gflops, 2) + 0.0,
            ]
        )
    print("\nComparison with the paper's Table II (nc=20, 640, paper counting convention):")
    print(
        format_table(
            [
                "model",
                "params M (ours)",
                "params M (paper)",
                "gradients M (ours)",
                "gradients M (paper)",
                "GFLOPs (ours)",
                "GFLOPs (paper)",
                "dGFLOPs",
            ],
            cmp_rows,
        )
    )
    print(
        "Paper params for -rep (12.2 M) and -gs-rep (10.2 M) cannot both hold: both necks feed "
        "the head identical channels,\nso a head change moves both rows equally. Our shared "
        "RepConv head removes 0.92 M in both rows; its GFLOPs match the paper.\nOurs counts "
        "the unused conv in params and gradients as the paper did (-gs: 10.9 / 10.9). The "
        "paper's -rep gradients sit 0.8 M below ours in both rows\n(a constant offset: the "
        "paper does not say which head layers it shares; GFLOPs pin the design)."
    )
