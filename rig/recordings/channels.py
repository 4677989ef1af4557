"""The run file's 1-D channels a recording may fill: name -> (SI units, meaning), and the
events of a blow found in them (rig.analysis.events).

The model's names, units and events (rig.model.vocabulary, docs/run-file.md), copied here
so that `rig import` does not load the model (numba: half a second of a fresh process);
tests/test_import.py checks the copies against the model's vocabulary."""

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

# the events in the order of a blow (rig.model.vocabulary.EVENT_DOCS)
EVENT_DOCS: dict[str, str] = {
    "key_starts": "key starts to move (key top travel exceeds the threshold)",
    "toe_meets_button": "jack toe meets the let-off button (contact 8 closes)",
    "let_off": "the jack escapes: it leaves the knuckle after its toe met the button "
               "(contact 7 opens)",
    "strike": "hammer meets the string (contact 12 closes)",
    "string_release": "hammer leaves the string (contact 12 opens)",
    "check": "back check catches the hammer tail after the string release (contact 4 closes)",
    "key_bottom": "key reaches its front felt (contact 2 closes)",
    "key_release": "key leaves its front felt for good (contact 2 opens for the last time)",
}
EVENT_ORDER = tuple(EVENT_DOCS)
KEY_MOVE_THRESHOLD_M = 2e-5  # the key has started when its top travelled this far
