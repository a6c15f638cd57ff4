"""Observation families: one module per family (its problems, equations and blocks, terms and report)."""
