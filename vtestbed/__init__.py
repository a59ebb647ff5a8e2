"""vtestbed: a virtual lab for robot joint-stiffness identification."""

__version__ = "0.1.0"
