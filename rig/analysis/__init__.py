"""Model against measurement: compare, diagnose, fit, synthesize, report.

    measurement.py  a measured (or synthetic) trial, its input to a model, noise
    events.py       events found in a measured trial's channels, without a model
    compare.py      simulate models against a trial: aligned errors per channel,
                    per phase of the blow and per event
    signature.py    what a residual looks like: bias, lag, oscillation, timing
    fit.py          least-squares fits of model or effect parameters
    diagnose/       which library effect removes the residual (held-out ranking)
    synth.py        measurement-like run files from a hidden truth model
    report.py       self-contained interactive HTML reports (Plotly)
    executor.py     where many independent evaluations run: local processes or Dask
"""
