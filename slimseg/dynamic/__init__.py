"""SLAM-facing reference logic: which feature points to drop, from model outputs."""
