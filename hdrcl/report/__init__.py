"""Quality figures of a merge, their plots, per-set reports, the HTML contact sheet and
tone-mapped previews.
"""
