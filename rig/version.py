"""rig's version (one place; ``rig.__version__`` and every run file and record read it)."""

__version__ = "0.1.0"
