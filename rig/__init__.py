"""rig: controller, data acquisition and model workbench for a grand-piano-action test rig."""

__version__ = "0.1.0"
