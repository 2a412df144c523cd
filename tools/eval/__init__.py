"""Scoring models and the physics unroller on held-out sequences with ground truth."""
