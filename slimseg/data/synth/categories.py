"""The synthetic dataset's categories: COCO names, COCO-style ids and mobility priors."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Category:
    """One object category.

    ``id``: COCO-json ``category_id`` (1-based, contiguous; the class index is ``id - 1``).
    ``mobility``: prior probability-like score on the quarter grid that the object moves
    (person 1.0 ... tv 0.0). ``height_m``: range of real-world heights in metres, used to
    size objects in sequence mode. ``weight``: relative sampling frequency in image mode.
    """

    id: int
    name: str
    mobility: float
    height_m: tuple[float, float]
    weight: float = 1.0


CATEGORIES: tuple[Category, ...] = (
    Category(1, "person", 1.0, (1.55, 1.9), weight=2.0),
    Category(2, "dog", 0.75, (0.45, 0.75)),
    Category(3, "sports ball", 0.75, (0.18, 0.3)),
    Category(4, "bottle", 0.5, (0.22, 0.35)),
    Category(5, "chair", 0.25, (0.8, 1.0)),
    Category(6, "tv", 0.0, (0.45, 0.8)),
)

NAMES: tuple[str, ...] = tuple(c.name for c in CATEGORIES)
MOBILITY: tuple[float, ...] = tuple(c.mobility for c in CATEGORIES)
BY_NAME: dict[str, Category] = {c.name: c for c in CATEGORIES}


def coco_categories() -> list[dict]:
    """The ``categories`` list of the COCO json, with the extra ``mobility`` key."""
    return [
        {"id": c.id, "name": c.name, "supercategory": "synth", "mobility": c.mobility}
        for c in CATEGORIES
    ]
