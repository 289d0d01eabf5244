"""Package exports imported on first use (PEP 562), so that importing one submodule imports
only what it needs: the device runtime (numpy and onnxruntime) uses ``wtml.physics.twoport``
and ``wtml.signals.phasor`` without the scipy that their siblings import."""

from __future__ import annotations

from collections.abc import Callable
from importlib import import_module


def lazy_exports(package: str, where: dict[str, str]
                 ) -> tuple[Callable[[str], object], Callable[[], list[str]]]:
    """The module ``__getattr__`` and ``__dir__`` of ``package`` exporting each name of
    ``where`` (``{name: module that holds it}``)."""

    def __getattr__(name: str):
        if name not in where:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(import_module(where[name]), name)

    def __dir__() -> list[str]:
        return sorted(set(vars(import_module(package))) | set(where))

    return __getattr__, __dir__
