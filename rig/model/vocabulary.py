"""The model's vocabulary: generalized coordinates, channel names with their units and
descriptions, and the events in the order of a blow, named as piano technicians mean
them (docs/run-file.md). Read by the model, the run files, the simulated rig and the
fingertip effect; rig.model.action re-exports it."""

from __future__ import annotations

from rig.model import kernel as k

COORDINATES = ("theta_k", "y_k", "theta_w", "theta_j", "theta_r", "theta_h", "u1", "v1", "v2",
               "z_b", "z_key", "z_whippen", "z_jack", "z_repetition", "z_hammer", "z_c2",
               "z_c3", "z_c4")  # z_*: bristle deflections (the pins', further contacts')
ANGLE_CHANNELS = {
    "key_angle": k.QK,
    "whippen_angle": k.QW,
    "jack_angle": k.QJ,
    "repetition_angle": k.QR,
    "hammer_angle": k.QH,
}
CHANNEL_UNITS: dict[str, str] = {
    "time": "s",
    "force": "N",
    **dict.fromkeys(ANGLE_CHANNELS, "rad"),
    **{n.replace("_angle", "_angular_velocity"): "rad/s" for n in ANGLE_CHANNELS},
    "hammer_head_velocity": "m/s",
    "hammer_head_x": "m",
    "hammer_head_y": "m",
    "key_dip": "m",
    "contact_force": "N",
    "contact_friction": "N",
    "contact_penetration": "m",
    "contact_penetration_rate": "m/s",
    "contact_slip": "m/s",
    "contact_point_x": "m",
    "shank_strain": "m/m",
    "shank_tip_deflection": "m",
    "key_lift": "m",
}
CHANNEL_DOCS: dict[str, str] = {
    "force": "force pressing the key top, downward",
    "key_angle": "key, ground -> key frame, counter-clockwise",
    "whippen_angle": "whippen, ground -> whippen frame",
    "jack_angle": "jack relative to the whippen",
    "repetition_angle": "repetition lever relative to the whippen",
    "hammer_angle": "hammer, ground -> hammer frame",
    "hammer_head_velocity": "vertical velocity of the striking felt's centre, + toward the string",
    "hammer_head_x": "ground x of the striking felt's centre",
    "hammer_head_y": "ground y of the striking felt's centre",
    "key_dip": "downward travel of the key top (Pk2) from rest",
    "contact_force": "normal force per contact (columns: contact ids)",
    "contact_friction": "tangential friction force per contact",
    "contact_penetration": "penetration per contact, + = touching",
    "contact_penetration_rate": "rate of penetration per contact, + = approaching",
    "contact_slip": "tangential slip speed per contact",
    "contact_point_x": "ground x of each contact's point",
    "shank_strain": "axial strain at the strain gauge (Eq. 4.1), + = tension",
    "shank_tip_deflection": "shank tip's transverse deflection in the shank frame",
    "key_lift": "key pivot's height above its rest on the balance rail (prismatic coordinate)",
}
CHANNEL_DOCS.update({n.replace("_angle", "_angular_velocity"):
                     f"rate of change of {n} ({CHANNEL_DOCS[n].split(',')[0]})"
                     for n in ANGLE_CHANNELS if n in CHANNEL_DOCS})

# the key has started to move when its top has travelled this far (m)
KEY_MOVE_THRESHOLD_M = 2e-5

# event name -> (contact id, direction), + = contact closes, - = opens
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
