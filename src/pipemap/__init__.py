"""pipemap: metric maps of pipe networks from a crawler robot's single camera."""

__version__ = "0.1.0"
