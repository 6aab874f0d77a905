"""Gaussian splatting avatars (later issues). May import torch."""
