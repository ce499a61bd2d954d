"""Sequence drivers: loops over a whole sequence or recording that open it, run the per-frame
chain (:mod:`slimseg.dynamic`) on every frame, write masks, CSVs, bags and recordings, draw
progress bars and make the report (scores, recall split, overlays) from the frames' trace."""
