"""thrsim: physically-based and learned simulation of acetabular reaming."""

__version__ = "0.3.0"
