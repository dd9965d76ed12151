"""The machine side, emulated: firmware models on a shared base
(:mod:`~fabkit.link.emulator.firmware`: planner, buffers, motion) with Marlin-like and
GRBL dialects, behind a serial-port look-alike (:mod:`~fabkit.link.emulator.port`) that
pyserial opens as ``sim://`` (:mod:`~fabkit.link.emulator.protocol_sim`)."""
