"""The robots: the robot model and link capsules (:mod:`.model`), the links' motion (:mod:`.link_motion`),
segment distances in numpy (:mod:`.segments`), the effective mass (:mod:`.effective_mass`) and the controller's
program file and its trajectory (:mod:`.program`), and the time scaling a closed controller applies to it (δ →
program time, the bounded ramp, the watchdog: :mod:`.time_scaling`)."""

__all__ = ["effective_mass", "link_motion", "model", "program", "segments", "time_scaling"]
