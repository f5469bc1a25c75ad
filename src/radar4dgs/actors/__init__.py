"""Actors without boxes (issue 24): the dynamic Gaussians of a trained run grouped into moving
objects by their motion (:mod:`.discover`), stored in ``RUN/actors.json`` (:mod:`.store`), drawn
(:mod:`.plot`), and edited at render time: removed, moved or re-timed (:mod:`.edit`), with the
pixels a removed actor hid that no training frame saw marked (:mod:`.background`)."""
