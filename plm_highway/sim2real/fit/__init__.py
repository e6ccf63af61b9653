"""Fitting the library's candidates: cross-validation folds, the fit problem, grid search and polishing, scores, uncertainty and selection."""
