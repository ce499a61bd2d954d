"""The diagnostic conditions of ``slam-eval``: a run's masks combined with the ground-truth
``dynamic/`` ones, to say where their ATE gap to the ground-truth masks comes from
(:mod:`slimseg.slam.conditions` applies them). A light module: the CLI names them at start-up.

- ``masks-within-gt``: only the mask pixels within :data:`NEAR_TRUTH_PX` of a dynamic pixel
  are kept: the masks at perfect precision, their recall unchanged;
- ``masks-plus-gt``: the ground truth added: the masks at perfect recall, their false positives
  kept.

Whichever of the two comes near the ground-truth masks' ATE names what the masks lack.
"""

from __future__ import annotations

#: ``within``: mask pixels this close (px) to a ground-truth dynamic pixel are kept (a mask's
#: dilation around its walker is not a false positive).
NEAR_TRUTH_PX = 10
#: ``--modes`` name → how the masks are combined with the ground truth.
DIAGNOSTIC: dict[str, str] = {"masks-within-gt": "within", "masks-plus-gt": "plus"}
#: What each combination shows (the results table's note).
NOTES: dict[str, str] = {
    "within": f"the masks within {NEAR_TRUTH_PX} px of dynamic/: their recall at perfect precision",
    "plus": "the masks plus dynamic/: perfect recall, their false positives kept",
}
