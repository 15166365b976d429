"""proto_brax: PROTO offline-to-online RL benchmark suite on Brax/JAX."""

__version__ = "0.1.0"
