"""Calibration: synthetic calibration sets and fitted curves f (shear) and g (normal)."""
