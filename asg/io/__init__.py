"""Outputs: point clouds (PCD, npy), figures, run folders."""
