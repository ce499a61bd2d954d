"""``slimseg data <action>``: build, convert, check and look at datasets."""

from __future__ import annotations

import argparse

from slimseg.cli import data_bag, data_coco, data_show, data_synth
from slimseg.cli.commands import COMMAND_HELP


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "data",
        help=COMMAND_HELP["data"],
        description="Build the embedded synthetic dataset, cut the COCO-20 subset, convert VOC, "
        "check a dataset for bad input, or draw augmented samples.",
    )
    actions = p.add_subparsers(dest="action", metavar="<action>", required=True)
    data_synth.add_parser(actions)
    data_coco.add_parsers(actions)
    data_show.add_parser(actions)
    data_bag.add_parsers(actions)
