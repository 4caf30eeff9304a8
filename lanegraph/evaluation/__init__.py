"""Evaluation: the lane metrics, datasets of sequences, ablations (their tables and plots)."""
