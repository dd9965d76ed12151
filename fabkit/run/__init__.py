"""``fabkit run``'s stages, one module each, in the order the data flows through them:
:mod:`~fabkit.run.inputs` (the options and the checks before any work),
:mod:`~fabkit.run.solve` (solve, check, the part, the layers, the verdict as designed),
:mod:`~fabkit.run.fabricate` (the machine files, verify, the shapes the sheet takes, send),
and :mod:`~fabkit.run.pipeline`, which runs them and writes the report."""
