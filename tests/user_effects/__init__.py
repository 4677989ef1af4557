"""Physics outside the effect library, written as a user would (docs/effects.md): the wide
diagnosis benchmark (benchmarks/diagnose_wide.py) hides them in some seeds, never as
candidates (issue 39)."""
