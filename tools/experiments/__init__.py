"""One-off experiments, kept because a doc cites their numbers; not maintained (README.md)."""
