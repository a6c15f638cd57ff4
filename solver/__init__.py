"""Pushbroom bundle adjustment library (no web code)."""

__version__ = "0.1.0"
