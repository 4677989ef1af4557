"""Calibration of the rig's sensors and of the motor's force map.

    settings    CalibrationSettings: records folder, maximum age, reference masses, shunt...
    records     one JSON file per calibration (content-hashed); newest valid per sensor
    bench       what a procedure reads: the simulated rig's sensors or the NI cards
    loadcell    known masses -> fit N per mV/V, non-linearity, hysteresis, uncertainty
    strain      offset nulling + shunt calibration -> gauge-factor (gain) adjustment
    motor       steps and ramps on a static surface -> force map, lag, dynamic model;
                ``MotorCompensation.demand`` is what the torque loop calls
    encoders    slow key travel -> each encoder counts, its direction and resolution
    touch       slow force ramps on the key -> down- and up-weight with their spread
                (`rig measure touch`; a ``touch`` record that runs embed)

Every procedure refuses bad data with a one-line ``ValueError`` naming the
point or field, and writes nothing in that case.
"""
