"""Pictures of a run and its report.

* :mod:`.pictures` — the per-view stress pictures, the Fig. 12-like sheet, the movie and the
  plots (``rackstress render``; one off-screen VTK window);
* :mod:`.report` — ``RUNDIR/report.html``: peak, pictures, plots, scene, stability margin, files.
"""
