"""From the design to millimetres: the part of the flat sheet that is made
(:mod:`~fabkit.field.part`, with outlines from :mod:`~fabkit.field.outlines`) and the
director and feature fields on it (:mod:`~fabkit.field.flat`) that the toolpath, the
writers and the verification sample."""
