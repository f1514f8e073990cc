"""Peers timed by `tflock bench` against tflock's kernels (optional dependencies, imported on demand)."""
