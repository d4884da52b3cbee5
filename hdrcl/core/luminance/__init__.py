"""Calibrated luminance maps: the fisheye chain (fisheye, fisheye_math) and glare metrics (glare)."""
