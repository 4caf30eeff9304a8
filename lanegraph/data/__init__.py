"""Data a user downloads, laid out for lanegraph: ``lanegraph data kitti`` (:mod:`lanegraph.data.kitti`)
and the lane ground truth lanegraph ships for it (this folder's ``*.lanes_gt.jsonl``, package data).

A layer above :mod:`lanegraph.evaluation` (the ground truth is checked with its reader before it is
written) that only the command line imports."""
