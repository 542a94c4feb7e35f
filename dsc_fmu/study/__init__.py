"""Step-size studies: cases, their cache, running them here or on Dask, analysis, stability
prediction, figures and the report."""
