"""Figures like the paper's: recordings, identified models, tracking runs, prediction errors, sweep
maps. Each function writes one figure atomically (PNG, or the format its path's suffix names: PDF,
SVG) and returns its path. They are matplotlib figures rendered with Agg outside pyplot, so the
caller's backend and pyplot figures are left alone."""
