"""The controllers: the vendor base (:mod:`.vendor`: the reading, the interface protocol, its error;
:mod:`.descriptor`: the speed input and the :class:`~.descriptor.Vendor` descriptor), one folder per vendor
(:mod:`.ur_rtde`, :mod:`.abb_rws`, :mod:`.abb_egm`) and the registry (:data:`.registry.VENDORS`)."""

__all__ = ["abb_egm", "abb_rws", "descriptor", "registry", "ur_rtde", "vendor"]
