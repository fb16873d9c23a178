"""gonio-brdf: acquisition package."""
