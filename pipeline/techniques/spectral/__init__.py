"""spectral: subsurface normals, low-pass filtered in the Laplace-Beltrami eigenbasis (Patro 2007)."""
