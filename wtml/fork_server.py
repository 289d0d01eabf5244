"""Imported last by the main job's fork server (:data:`wtml.pipeline.PRELOAD`): freezes what
the server holds, so the lanes forked from it share those pages instead of copying them.

A forked process shares its parent's pages until it writes to one. Python's garbage collector
writes to every object it visits (its bookkeeping lives in the object's header), so each lane's
first collections copied the pages of every object the server had imported: torch, lightning,
scikit-learn, onnxruntime. ``gc.freeze`` moves them out of the collector's reach. Measured: a
texture export forked from the server, the server's and the lane's proportional set sizes
together at its end, 820 MB plain and 730 MB frozen (twice each, to the MB).
"""

import gc

gc.collect()
gc.freeze()
