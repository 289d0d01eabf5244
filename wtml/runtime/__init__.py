"""The device runtime: onnxruntime sessions on export folders (``predict``), recordings as
instruments write them (``recordings``, ``instruments``), the contact timing rule offline and
online (``contacts``), the onset and texture rows, and ``wtml stream`` (``stream``).

Imports numpy and onnxruntime (pyyaml for profiles and devices; scipy only to resample a
record, npTDMS only to read a TDMS file), never torch, lightning, numba or scikit-learn: what
``pip install wtml`` installs (tests/test_runtime_install.py). Making an export folder is
:mod:`wtml.exporters`.
"""
