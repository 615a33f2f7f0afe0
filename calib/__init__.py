"""Radiometric calibration: dark frames, flat field, HDR from exposure brackets, white
reference, lamp drift and the ArUco region of interest -> absolute BRDF with uncertainty."""
