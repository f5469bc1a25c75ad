"""Exports of a trained scene to formats that other tools open (standard 3DGS ``.ply``)."""

from radar4dgs.export.ply import SH_C0, read_gaussians_ply, write_gaussians_ply

__all__ = ["SH_C0", "read_gaussians_ply", "write_gaussians_ply"]
