"""Many tasks at once: batches planned and finished (:mod:`.batch`: runs reused, chunks cut and
merged) and the runners that only schedule tasks (:mod:`.runners`: in-process, or a plugin's --
Dask's, a third party's)."""
