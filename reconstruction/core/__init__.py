"""The numerical core: geometry, BRDF models, energy, colour, metrics, the renderer, scenes."""
