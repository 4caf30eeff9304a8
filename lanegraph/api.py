"""lanegraph's application API: what an add-on (a command plugin, a runner) and a notebook may use
beyond the plugin author's core modules.

The command line's own add-ons are plugins (``lanegraph_tune``, ``lanegraph_report`` with ``report``
and ``eval``, ``lanegraph_dask``, ``lanegraph_data`` with ``data kitti``, in ``plugins/``) and
import lanegraph only from here and from the core's public modules, as a third party's would
(``tests/engine/test_layout.py`` checks it); everything else in lanegraph may change between
releases. This module is a front end: it stands above every layer, and only re-exports.

- the run service: :class:`Session`, whose methods run, batch, ablate and report;
- for a command (``lanegraph.commands`` entry points, :mod:`lanegraph.cli`): :func:`handled` (the one
  place errors become exit codes), :func:`session` (the service a command calls), the option sets
  and types the core's commands use;
- then, in a block each, the names the built-in add-ons use beyond those (commented with the add-on).
"""

from __future__ import annotations

from .cli._common import (
    FOLDER,
    PATH,
    dataset_cache_options,
    keeping_options,
    parse_frames,
    scale_out_options,
    session,
)
from .cli._errors import handled
from .evaluation.metrics import read_ground_truth  # lanegraph_data (data kitti)
from .records import owned  # lanegraph_data (data kitti)
from .service import Session

# isort: split
# lanegraph_tune
from .batches.batch import BatchRun
from .evaluation.dataset import POOLED, load_dataset, read_gt
from .evaluation.metrics import evaluate, read_predictions
from .records.folder import check as check_folder
from .records.provenance import write_resolved_graph
from .records.record import TuneEntry
from .records.results import LANES, find_result
from .run.cache import ResultCache, digest  # ResultCache: a batch's own cache (docs/distributed.md)
from .run.task import describe_error
from .service.keeping import command_kept, dataset_identity, result_cache

# isort: split
# lanegraph_report (eval)
from .evaluation.dataset import evaluate_sequences
from .evaluation.metrics import select_frames
from .evaluation.metrics_extra import culane_metrics, lateral_error_cm, tusimple_metrics
from .evaluation.scoring import pct, run_ground_truth, run_lanes, run_selection, score, some_frames
from .run.sources import read_calibration

# isort: split
# lanegraph_dask: a runner's life cycle, the tasks it runs (``task.execute()``) and their outcomes
from .batches.batch import Progress
from .batches.runners import BaseRunner
from .run.task import RunTask, TaskOutcome

# isort: split
# lanegraph_report (the report; with POOLED, LANES, evaluate, evaluate_sequences, find_result, read_gt,
# select_frames above)
from .evaluation.dataset import single_sequence
from .evaluation.metrics import read_jsonl
from .evaluation.plots import nearest_on_box, place_labels, text_width
from .records.record import read_record
from .records.results import describe
from .run.sources import detect_source, open_source, select_source

__all__ = [
    "FOLDER",
    "PATH",
    "Session",
    "dataset_cache_options",
    "handled",
    "keeping_options",
    "owned",
    "parse_frames",
    "read_ground_truth",
    "scale_out_options",
    "session",
    # lanegraph_tune
    "BatchRun",
    "LANES",
    "POOLED",
    "ResultCache",
    "TuneEntry",
    "check_folder",
    "command_kept",
    "dataset_identity",
    "describe_error",
    "digest",
    "evaluate",
    "find_result",
    "load_dataset",
    "read_gt",
    "read_predictions",
    "result_cache",
    "write_resolved_graph",
    # lanegraph_report (eval)
    "culane_metrics",
    "evaluate_sequences",
    "lateral_error_cm",
    "pct",
    "read_calibration",
    "run_ground_truth",
    "run_lanes",
    "run_selection",
    "score",
    "select_frames",
    "some_frames",
    "tusimple_metrics",
    # lanegraph_dask
    "BaseRunner",
    "Progress",
    "RunTask",
    "TaskOutcome",
    # lanegraph_report (the report)
    "describe",
    "detect_source",
    "nearest_on_box",
    "open_source",
    "place_labels",
    "read_jsonl",
    "read_record",
    "select_source",
    "single_sequence",
    "text_width",
]
