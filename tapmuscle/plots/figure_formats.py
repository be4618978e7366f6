"""The file formats tapmuscle's commands write figures in (``--figure-format``).

Kept apart from the figures themselves so that the command line names them without importing
matplotlib.
"""

__all__ = ["FIGURE_FORMATS", "checked_figure_format"]

#: PNG for the screen; PDF and SVG, vector, for a publication (:func:`tapmuscle.plots.figures.save_figure`
#: embeds PDF fonts as TrueType and keeps SVG text as text, so that a journal's checks and an editor take them).
FIGURE_FORMATS = ("png", "pdf", "svg")


def checked_figure_format(figure_format: str) -> str:
    """``figure_format``, once it is one of :data:`FIGURE_FORMATS`.

    Parameters
    ----------
    figure_format : str
        The format asked for.

    Raises
    ------
    ValueError
        Any other value, named with the formats there are.
    """
    if figure_format not in FIGURE_FORMATS:
        raise ValueError(f"figure_format must be one of {', '.join(FIGURE_FORMATS)}, got {figure_format!r}")
    return figure_format
