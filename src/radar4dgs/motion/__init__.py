"""Dynamic motion (DESIGN.md stage 6): the VGPT invertible deformation field, pseudo scene flow from
optical flow, radar Doppler association, the two losses, and the standalone fit.

Modules: :mod:`.field` (``DeformationField``, ``FieldConfig``), :mod:`.flow` (DIS/RAFT flow,
consistency, lifting, ``prepare_flow``, ``motion_frontend_metrics``), :mod:`.association`
(nearest dynamic radar point), :mod:`.losses` (``flow_loss``, ``radar_loss``), :mod:`.fit`
(``run_fit``, ``MotionConfig``) and :mod:`.command` (``radar4dgs fit-motion``). Importing this
package imports torch (through the field); the CLI imports it only for ``fit-motion``.
"""

from radar4dgs.motion.field import DeformationField, FieldConfig, normalization_from_points
from radar4dgs.motion.losses import flow_loss, flow_residual, radar_loss, radar_residual

__all__ = ["DeformationField", "FieldConfig", "normalization_from_points", "flow_loss", "flow_residual",
           "radar_loss", "radar_residual"]
