"""Ablation sweeps: one recipe, one seed, several variants → the paper's Table II columns."""
