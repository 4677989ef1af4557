"""The simulated rig: plays the cards, the drive and the action for `backend: sim`.

    drive_model   the drive+motor third-order process model (thesis Appendix D)
    sensors       load cell, strain gauge and encoder models with seeded true
                  sensitivities/offsets (reused by calibration and `rig synth`)
    rig           SimRig: steps the action model under the drive's force and
                  produces what the cards would read at 2 kHz
    fifo          the simulated input buffer shared with the acquisition process
    drive_pty     a simulated Kollmorgen drive answering on a pseudo-terminal
"""
