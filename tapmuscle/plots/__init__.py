"""Figures like the paper's (matplotlib, Agg backend): recordings, identified models, tracking runs,
prediction errors, sweep maps. Each function writes one PNG atomically and returns its path."""
