"""lanegraph_data: ``lanegraph data``, datasets a user downloads laid out as lanegraph's sources
read them, with the lane ground truth lanegraph ships (package data). ``lanegraph data kitti``:
:mod:`lanegraph_data.kitti`. A command of the ``lanegraph.commands`` entry-point group, like a third
party's; it imports no node plugin (``lanegraph --help`` loads no numba)."""
