"""gonio-brdf: reconstruction package."""
