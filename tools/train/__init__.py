"""Training SelfUnroll (train.py) and what a run needs before it starts (contrast cache, gate radii)."""
