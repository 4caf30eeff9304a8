"""Evaluation: the lane metrics, datasets of sequences, ablations."""
