"""Motion estimation (DESIGN.md stage 6, front end): pseudo scene flow from optical flow and
radar Doppler association.

Modules: :mod:`.config` (``FlowConfig``, torch-free), :mod:`.optical_flow` (DIS/RAFT flow,
forward-backward consistency), :mod:`.rigid` (whole-object translations), :mod:`.objects_flow`
(radar-guided object motion: :mod:`.object_hints` radar objects in the image and their predicted
motion, :mod:`.warp_match` the matched affine warp), :mod:`.sampling`
(bilinear sampling), :mod:`.lift` (lifting to 3D, outlier rejection), :mod:`.flow` (the scene
level: ``prepare_flow``, the prepared ``flow/`` folder), :mod:`.metrics`
(``motion_frontend_metrics``) and :mod:`.association` (nearest dynamic radar point). The
deformation field they supervise is part of the scene model (:mod:`radar4dgs.model.field`), its
losses are in :mod:`radar4dgs.metrics.losses`, and its standalone fit is
:mod:`radar4dgs.train.fit_motion`.
"""
