"""The run file's 1-D channels a recording may fill: name -> (SI units, meaning).

The model's names and units (rig.model.vocabulary, docs/run-file.md), copied here so that
`rig import` does not load the model (numba: half a second of a fresh process);
tests/test_import.py checks the copy against the model's vocabulary."""

from __future__ import annotations

CHANNELS: dict[str, tuple[str, str]] = {
    'force': ('N',
        'force pressing the key top, downward'),
    'key_angle': ('rad',
        'key, ground -> key frame, counter-clockwise'),
    'whippen_angle': ('rad',
        'whippen, ground -> whippen frame'),
    'jack_angle': ('rad',
        'jack relative to the whippen'),
    'repetition_angle': ('rad',
        'repetition lever relative to the whippen'),
    'hammer_angle': ('rad',
        'hammer, ground -> hammer frame'),
    'key_angular_velocity': ('rad/s',
        'rate of change of key_angle (key)'),
    'whippen_angular_velocity': ('rad/s',
        'rate of change of whippen_angle (whippen)'),
    'jack_angular_velocity': ('rad/s',
        'rate of change of jack_angle (jack relative to the whippen)'),
    'repetition_angular_velocity': ('rad/s',
        'rate of change of repetition_angle (repetition lever relative to the whippen)'),
    'hammer_angular_velocity': ('rad/s',
        'rate of change of hammer_angle (hammer)'),
    'hammer_head_velocity': ('m/s',
        "vertical velocity of the striking felt's centre, + toward the string"),
    'hammer_head_x': ('m',
        "ground x of the striking felt's centre"),
    'hammer_head_y': ('m',
        "ground y of the striking felt's centre"),
    'key_dip': ('m',
        'downward travel of the key top (Pk2) from rest'),
    'shank_strain': ('m/m',
        'axial strain at the strain gauge (Eq. 4.1), + = tension'),
    'shank_tip_deflection': ('m',
        "shank tip's transverse deflection in the shank frame"),
    'key_lift': ('m',
        "key pivot's height above its rest on the balance rail (prismatic coordinate)"),
    "load_cell_ratio": ("V/V", "load cell bridge reading"),
    "strain_ratio": ("V/V", "strain gauge bridge reading"),
}
