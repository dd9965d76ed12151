"""The problem a design solves: the spec (:mod:`~fabkit.problem.spec`), the material's
response (:mod:`~fabkit.problem.material`), the whitelisted expressions users write
(:mod:`~fabkit.problem.expr`) and the target surfaces (:mod:`~fabkit.problem.surfaces`)."""
