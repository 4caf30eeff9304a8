"""lanegraph_dask: runs the tasks of a batch on a Dask cluster (``--scheduler``); the
``distributed`` extra. (Being moved here from ``lanegraph.batches.distributed``.)"""
