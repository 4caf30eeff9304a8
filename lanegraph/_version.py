"""lanegraph's version (a module of its own: what every other module may import)."""

__version__ = "0.1.0"
