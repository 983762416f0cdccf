"""Baking assets: one asset's stages through the content-hash cache, the batch, worker supervision,
Dask clusters."""
