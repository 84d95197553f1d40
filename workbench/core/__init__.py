"""Foundations: the LTI model type, state-space arithmetic, errors, safe files."""
