"""lanegraph_tune: ``lanegraph tune``, cross-validated search of a graph's params with Optuna (the
``tune`` extra, imported only when a tune runs); docs/tune.md.

A command plugin as a third party's would be: the entry point ``tune = "lanegraph_tune.cli:tune"`` of
the ``lanegraph.commands`` group, importing lanegraph only from :mod:`lanegraph.api` and the core's
public modules.

- :mod:`.cli`: the click command; :mod:`.command`: the command on the run service (folder, record,
  tracking, what it says);
- :mod:`.search`: the score, the leave-one-group-out folds and the search (:class:`~.search.Tuner`);
- :mod:`.space`: space files, checked against the graph; :mod:`.runs`: its one call into the run
  service's batches and its Optuna study; :mod:`.output`: its tables and tuned graph;
  :mod:`.report`: its static page.
"""
