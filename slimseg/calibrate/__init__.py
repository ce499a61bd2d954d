"""``slimseg calibrate``: a model's masking settings, chosen on sequences it never trained on."""
