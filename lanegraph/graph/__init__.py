"""The graph model: graph files (:mod:`.loader`), ``extends`` and ``--set``, validation as a chain of
named passes (:mod:`.model`)."""
