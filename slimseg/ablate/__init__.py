"""Ablation sweeps: one recipe, several arms (zoo variants or spec overrides) and seeds →
the paper's Table II columns, mean ± spread over seeds, latency at several sizes."""
