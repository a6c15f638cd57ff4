"""Quality control: statistics computed from an adjusted problem (tests, reliability, precision)."""
