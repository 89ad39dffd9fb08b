"""The robots: the robot model and link capsules (:mod:`.model`), the links' motion (:mod:`.link_motion`),
segment distances in numpy (:mod:`.segments`), the effective mass (:mod:`.effective_mass`) and the controller's
program file and its trajectory (:mod:`.program`)."""

__all__ = ["effective_mass", "link_motion", "model", "program", "segments"]
