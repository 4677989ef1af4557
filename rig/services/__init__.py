"""Services behind the CLI: simulate, run, calibrate, compare, diagnose."""
