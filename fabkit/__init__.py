"""fabkit: design flat active sheets that morph into several 3D shapes, and fabricate them.

Data flows one way::

    spec -> surfaces + material -> solve -> design -> check / plot -> toolpath -> export -> machine

The public API, one function per stage (docs/api.md has a script that uses every one);
lengths in mm unless a name says otherwise, a design's in design units:

=====================  ==========================================================
``load_spec(path)``    a spec TOML file (or a shipped ``examples/...``) -> ``Spec``
``solve(spec)``        -> ``Design``: arrays on the (Nu, Nv) grid, design units
``check(design)``      isometry and curvature residuals (dimensionless medians and
                       95th percentiles per target) -> ``CheckReport``
``plan_toolpath``      ``(design, machine, size_mm)`` -> ``Plan`` (``.toolpath``, mm)
``write_machine_file`` ``(toolpath, machine, "gcode", path)`` -> ``Exported``
``verify``             ``(design, path)``: the file read back -> ``Verification``
                       (director error in degrees, coverage, the sheet simulated)
``send``               ``(path, port)``: stream G-code to a port or ``sim://`` ->
                       ``SendReport`` (lines, seconds)
``load_machine(name)`` a machine profile by name or .toml path -> ``MachineProfile``
=====================  ==========================================================

Every name is imported when first used (a module ``__getattr__``), so ``import fabkit``
loads no stage: the command line starts as fast as before. ``fabkit.verify`` is also the
subpackage :mod:`fabkit.verify`, made callable: called, it is :func:`fabkit.api.verify`.
"""

from __future__ import annotations

import importlib
import types

from fabkit.errors import FabkitError
from fabkit.version import __version__

TYPE_CHECKING = False  # typing.TYPE_CHECKING without importing typing (5 ms)
if TYPE_CHECKING:  # what the lazy names are, for type checkers and editors
    from typing import Any

    from fabkit.api import plan_toolpath, solve, write_machine_file
    from fabkit.design.check import CheckReport, Tolerances
    from fabkit.design.check import check_design as check
    from fabkit.design.design import Design
    from fabkit.link.host.send import send_file as send
    from fabkit.link.host.session import SendReport
    from fabkit.machines import MachineProfile, load_machine
    from fabkit.problem.spec import Spec, load_spec
    from fabkit.toolpath.model import Toolpath
    from fabkit.toolpath.plan import Plan
    from fabkit.verify.machine_file import Verification


_PUBLIC = {
    "load_spec": "fabkit.problem.spec:load_spec",
    "solve": "fabkit.api:solve",
    "check": "fabkit.design.check:check_design",
    "plan_toolpath": "fabkit.api:plan_toolpath",
    "write_machine_file": "fabkit.api:write_machine_file",
    "verify": "fabkit.api:verify",
    "send": "fabkit.link.host.send:send_file",
    "load_machine": "fabkit.machines:load_machine",
    "Spec": "fabkit.problem.spec:Spec",
    "Design": "fabkit.design.design:Design",
    "CheckReport": "fabkit.design.check:CheckReport",
    "Tolerances": "fabkit.design.check:Tolerances",
    "MachineProfile": "fabkit.machines:MachineProfile",
    "Toolpath": "fabkit.toolpath.model:Toolpath",
    "Plan": "fabkit.toolpath.plan:Plan",
    "Verification": "fabkit.verify.machine_file:Verification",
    "SendReport": "fabkit.link.host.session:SendReport",
}
"""Every public name and where it lives (``module:attribute``), imported on first use."""

__all__ = [
    "load_spec",
    "solve",
    "check",
    "plan_toolpath",
    "write_machine_file",
    "verify",
    "send",
    "load_machine",
    "Spec",
    "Design",
    "CheckReport",
    "Tolerances",
    "MachineProfile",
    "Toolpath",
    "Plan",
    "Verification",
    "SendReport",
    "FabkitError",
    "__version__",
]


def _public(name: str) -> Any:
    """The object a public name stands for (imports its module)."""
    module, _, attribute = _PUBLIC[name].partition(":")
    return getattr(importlib.import_module(module), attribute)


def __getattr__(name: str) -> Any:
    if name not in _PUBLIC:
        raise AttributeError(f"module 'fabkit' has no attribute {name!r}")
    value = _public(name)
    globals()[name] = value  # looked up once
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})


class _CallablePackage(types.ModuleType):
    """A subpackage that is also the public function of its name: ``fabkit.verify`` is
    the package :mod:`fabkit.verify` (``fabkit.verify.machine_file`` ...), and
    ``fabkit.verify(design, machine_file)`` calls :func:`fabkit.api.verify`. The import
    system sets a subpackage as its parent's attribute when it is first imported, so the
    name cannot be the function itself."""

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return _public(self.__name__.rpartition(".")[2])(*args, **kwargs)


# fabkit/verify/__init__.py is a docstring: importing it loads no stage
importlib.import_module("fabkit.verify").__class__ = _CallablePackage


def _show_in_notebooks() -> None:
    """In a notebook (an IPython shell is running), show fabkit's values as HTML
    (:mod:`fabkit.plot.notebook`); elsewhere do nothing and import nothing."""
    import sys

    ipython = sys.modules.get("IPython")
    shell = ipython.get_ipython() if ipython is not None else None
    if shell is not None and hasattr(shell, "display_formatter"):
        importlib.import_module("fabkit.plot.notebook").register(shell)


_show_in_notebooks()
