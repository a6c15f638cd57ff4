"""Geometry shared by the solver and the simulator: geodesy (CRS <-> ECEF <-> local frame) and the sensor (chips, the chip of a column)."""
