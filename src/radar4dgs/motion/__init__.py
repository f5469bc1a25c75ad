"""Motion estimation (DESIGN.md stage 6, front end): pseudo scene flow from optical flow and
radar Doppler association.

Modules: :mod:`.flow` (DIS/RAFT flow, consistency, lifting, ``prepare_flow``,
``motion_frontend_metrics``) and :mod:`.association` (nearest dynamic radar point). The
deformation field they supervise is part of the scene model (:mod:`radar4dgs.model.field`), its
losses are in :mod:`radar4dgs.metrics.losses`, and its standalone fit is
:mod:`radar4dgs.train.fit_motion`.
"""
