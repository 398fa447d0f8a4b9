"""Marker cleanup after Park & Hodgins (2006) §4: marker surface, local reference
frames, merging broken trajectories, local-PCA hole filling, smoothing in local frames,
with the baselines they are measured against."""
