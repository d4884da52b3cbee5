"""Grouping a shoot into bracket sets: the rules (rules), ladders (ladder), scene comparison (scene, compare) and splitting (splitting: runs, bridges)."""
