"""The run: the parts of the 500 Hz loop's run around rig.services.run (docs/architecture.md).

``acquisition`` (the acquisition process), ``journal`` (the run file's journal and
``rig recover``), ``recovery`` (the run's end), ``supervisor`` (safe when the loop dies),
``hook`` (the loop's controller hook), ``drive`` (the drive's serial link), ``scheduling``
(the loop thread's OS set-up), ``backends`` (the one place choosing a backend).
"""
