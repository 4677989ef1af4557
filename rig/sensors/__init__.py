"""The sensors: the sensor table, the run-file channels and calibrations, raw -> SI
(``table``; docs/architecture.md, "Add a sensor"), and the units SI channel values are
displayed in (``display``)."""
