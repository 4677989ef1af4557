"""``python -m rig``: the same command line as the ``rig`` script."""

from rig.cli import main

main()
