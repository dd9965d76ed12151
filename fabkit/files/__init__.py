"""The files at fabkit's edges: writing atomically (:mod:`~fabkit.files.atomic`), reading
a user's file within its limits (:mod:`~fabkit.files.readfile`, and through it
:mod:`~fabkit.files.npzfile` and :mod:`~fabkit.files.tomlfile`), and the files that ship
with the package (:mod:`~fabkit.files.shipped`)."""
