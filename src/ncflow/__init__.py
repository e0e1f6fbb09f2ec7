"""ncflow: correspondence-free matching and interpolation of articulated 3D shapes."""
__version__ = "0.1.0"
