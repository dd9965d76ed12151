"""The host side of the link: the preflight check of a job against the machine profile
(:mod:`~fabkit.link.host.preflight`), the firmware protocols (Marlin-like, GRBL), the
sending session and :func:`~fabkit.link.host.send.send_file`; the printer hosts that stream
a file themselves, OctoPrint and Moonraker, over HTTP (:mod:`~fabkit.link.host.hosts`)."""
