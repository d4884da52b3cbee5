"""Exposures: measured from the pixels with a fitted curve (fit) or a known one (known), and virtual photographs from a map (virtual)."""
