"""The exact stepper's shared kernel: a regime's step map in the eigenbasis of its state map
(:func:`eigenbasis`), and records split into blocks stepped side by side on the cores this
process may use (:func:`record_blocks`, on :func:`wtml.cores.available_cores`).

:class:`wtml.physics.modal.ModalTransducer` steps its walls and the loads that
:mod:`wtml.physics.contact` and :mod:`wtml.physics.friction` step with these, each importing
this module only: the loads know nothing of the modal model but the maps it hands them.
"""

from __future__ import annotations

import numpy as np

from wtml.cores import available_cores

BLOCK = (32, 64)
"""The fewest and most records stepped side by side in one call of the stepper: their maps
stay in cache and each step's arithmetic runs across records in vector registers (measured:
below 24 records per call the time per record-step doubles)."""


def record_blocks(bsz: int, threads: int | None) -> list[slice]:
    """The records split into blocks of :data:`BLOCK` size, one per thread where there are
    enough (``threads``: default every core this process may use)."""
    size = min(BLOCK[1], max(BLOCK[0], -(-bsz // (threads or available_cores()))))
    return [slice(lo, min(bsz, lo + size)) for lo in range(0, bsz, size)]


def eigenbasis(maps: np.ndarray) -> tuple[np.ndarray, ...]:
    """One regime's exact step (:meth:`wtml.physics.modal.ModalTransducer.step_matrices`,
    ``(B, ns+4, ns+4)``) in the eigenbasis of its state map, which is diagonal:
    ``w_{k+1} = λ w_k + G [E, Ė, g]``.

    The state map is real, so its eigenvalues are real or come in conjugate pairs; one of each
    pair is kept (the other is its conjugate) and counted twice in every real quantity formed
    from it. Returns, for m kept modes: ``lam`` (B, m), ``gain`` (B, m, 4) on ``[E, Ė, g,
    Ė_out]`` (the last is 0), ``out`` (B, 4, m) and ``feed`` (B, 4, 4) so that the outputs are
    ``Re(out @ w) + feed @ [E, Ė, g, Ė_out]``, and the changes of basis ``to_modal`` (B, m, ns)
    and ``to_state`` (B, ns, m) with ``x = Re(to_state @ w)``. Modes a record does not need
    (fewer kept than m) have ``λ = 0`` and zero columns. Raises ValueError where the map is
    too close to defective to be diagonalised (a mode's frequency at a multiple of half the
    step rate).
    """
    ns = maps.shape[2] - 4
    lam, vec = np.linalg.eig(maps[:, :ns, :ns])
    inv = np.linalg.inv(vec)
    keep = lam.imag >= 0
    order = np.argsort(~keep, axis=1, kind="stable")[:, :int(keep.sum(1).max())]
    weight = np.take_along_axis(np.where(lam.imag > 0, 2.0, 1.0) * keep, order, 1)
    lam = np.take_along_axis(lam, order, 1)
    used = weight > 0
    to_modal = np.take_along_axis(inv, order[:, :, None], 1) * used[:, :, None]
    to_state = np.take_along_axis(vec, order[:, None, :], 2) * weight[:, None, :]
    rebuilt = np.einsum("brj,bj,bjc->brc", to_state, lam * used, to_modal).real
    row = np.abs(maps[:, :ns, :ns]).max(2, keepdims=True)
    if np.any(np.abs(rebuilt - maps[:, :ns, :ns]) > 1e-9 * row):
        raise ValueError("dt: the step map cannot be diagonalised accurately at this step (a "
                         "mode at a multiple of half the step rate?); choose another dt")
    return (lam * used, to_modal @ maps[:, :ns, ns:], maps[:, ns:, :ns] @ to_state,
            maps[:, ns:, ns:], to_modal, to_state)
