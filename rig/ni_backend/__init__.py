"""The NI backend: the lab's cards through the real ``nidaqmx`` package.

    daq     NiDaq (loop side: PCI-6229 analog output to the drive, 500 Hz pacing) and
            NiReader (acquisition side: SCXI-1520 bridges, PCI-6602 encoders, 2 kHz)
    bench   NiBench: what the calibration procedures read on the real rig

Same inner layout as ``rig.sim_backend``; ``rig.loop.backends`` chooses between them.
"""
