"""Pictures of a run: the Fig. 12-like sheet, per-view images, the movie and plots (pyvista)."""
