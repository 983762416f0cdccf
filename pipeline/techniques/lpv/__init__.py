"""lpv: subsurface light propagation volumes through the medium's grid (Børlum et al. 2011)."""
