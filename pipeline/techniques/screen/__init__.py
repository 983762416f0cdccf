"""screen: image-space importance-sampled dipole gather (Mertens et al. 2003)."""
