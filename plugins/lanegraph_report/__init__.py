"""lanegraph_report: the HTML report of a run or an ablation (``lanegraph report``, ``--report``).
(Being moved here from ``lanegraph.presentation.report``.)"""
