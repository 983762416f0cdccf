"""Tiny fixtures several test modules share."""

from sssbake.pipeline.baked import Fallback

# A plausible marble-like fallback with distinct values in every field, so a field swapped on export shows.
FALLBACK = Fallback(
    base_color=(0.83, 0.79, 0.75),
    thickness_texture=None,
    thickness_factor=2.0,
    attenuation_color=(0.9, 0.8, 0.7),
    attenuation_distance=4.0,
    diffuse_transmission_factor=0.4,
    diffuse_transmission_color=(1.0, 0.95, 0.9),
    ior=1.5,
)
