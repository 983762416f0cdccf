"""kernels: texture-atlas local filter kernels plus a sparse vertex-to-vertex throughput matrix (Lensch et al. 2002)."""
