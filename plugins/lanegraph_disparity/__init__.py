"""lanegraph_disparity node plugin."""

from lanegraph import hookimpl


@hookimpl
def lanegraph_node_types():
    return []
