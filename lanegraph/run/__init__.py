"""Running graphs: the executor and the pieces around it (result cache, checkpoints, sources), the
units of work of a batch and the runners that execute them."""
