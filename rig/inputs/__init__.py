"""What users write: ``config`` (the rig file, pydantic, strict), ``params`` (model
parameters, the YAML loader and Eq. D.1's time unit), ``profiles`` (force profiles)."""
