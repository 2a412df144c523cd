"""The tools of the SelfUnroll model: the PyTorch mirror, the weights format, the physics reference."""
