"""wtml: decoding a piezoelectric whisker transducer.

Physics (``wtml.physics``) and signal processing (``wtml.signals``) are pure numpy/scipy,
complex128 and SI units; see ``shared/physics.md`` for every equation and convention.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("wtml")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0.0.0+unknown"
