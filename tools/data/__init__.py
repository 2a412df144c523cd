"""Sequences for training and evaluation: readers, the photo-based and the second generator, live feeds."""
