"""Meshes in and out of shape: the scene model, the loaders (confined to an asset's folder), cleaning
and welding, the atlas, thickness, simplification and the baked-asset model the exporters write."""
