"""What a run keeps, and how it is read back: ``run.json`` and ``command.json`` (:mod:`.record`), the
result files (:mod:`.results`), one run per output folder (:mod:`.folder`) and what lanegraph owns
in it (:mod:`.owned`), provenance (:mod:`.provenance`), the checkpoint (:mod:`.checkpointing`) and
its file format (:mod:`.resume`). It imports only the core."""
