"""The PyTorch peers the C++ benches (bench/) call in the same run."""
