"""HTTP orientation server (OGC API - Processes) wrapping the solver package."""
