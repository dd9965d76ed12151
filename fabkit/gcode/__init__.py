"""The G-code language once: how each firmware reads a command (:mod:`~fabkit.gcode.read`),
its distance modes (:mod:`~fabkit.gcode.modes`) and where its moves go
(:mod:`~fabkit.gcode.position`) and how long a job takes (:mod:`~fabkit.gcode.duration`,
the one estimate the writer's header, the report, ``export`` and ``send`` quote); every
reader of a job (the pre-flight check, ``fabkit verify``, the duration estimate) goes
through these."""
