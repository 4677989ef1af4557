"""Recordings: rig's own run files (rig.recordings.runfile: the HDF5 layout, writer and
reader) and recordings made outside rig: read other labs' files (text, TDMS, HDF5), calibrate their
columns through a map (rig.recordings.mapfile), and split a long recording into strokes
(rig.recordings.segment). The service writing the run file is rig.services.importer;
the command and the map's format are in docs/import.md."""
