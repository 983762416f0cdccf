"""The subsurface techniques, one subpackage each, and the registry every stage iterates over."""
