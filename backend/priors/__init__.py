"""Priors per view, aligned with images/: albedo predictors, depth predictors and their alignment to the
SfM scale, and the brick-window schedule for video albedo models (paper 3.2.1)."""
