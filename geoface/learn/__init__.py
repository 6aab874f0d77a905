"""Neural consumers of geometry images (later issues). May import torch."""
