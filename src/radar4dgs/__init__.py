"""radar4dgs: 4D-radar Gaussian splatting for dynamic driving scenes."""
__version__ = "0.1.0"
