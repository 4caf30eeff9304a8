"""``python -m lanegraph``: the same as the ``lanegraph`` command."""

from .cli import main

if __name__ == "__main__":
    main()
