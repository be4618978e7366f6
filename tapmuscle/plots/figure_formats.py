"""The file formats tapmuscle's commands write figures in (``--figure-format``).

Kept apart from the figures themselves so that the command line names them without importing
matplotlib.
"""

__all__ = ["FIGURE_FORMATS"]

#: PNG for the screen; PDF and SVG, vector, for a publication (:func:`tapmuscle.plots.figures.save_figure`
#: embeds PDF fonts as TrueType and keeps SVG text as text, so that a journal's checks and an editor take them).
FIGURE_FORMATS = ("png", "pdf", "svg")
