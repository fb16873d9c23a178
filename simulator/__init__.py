"""gonio-brdf: simulator package."""
