"""The reference runtime: moderngl on EGL draws render items with the shipped GLSL; image metrics,
the stock-viewer check and the tradeoff sweeps' shared parts."""
