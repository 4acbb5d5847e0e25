"""The Embree boundary: triangles recentred in float64 then cast to float32, and the one
chunked, thread-pooled loop every ray caster uses.

The only module that imports embreex. Knows nothing about the methods that call it;
the word "scene" is kept for what a file holds.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ._types import FloatArray, IndexArray
from .constants import INFINITE_DISTANCE
from .errors import InputError
from .progress import Progress

__all__ = ["INFINITE_DISTANCE", "Tracer", "split", "trace_chunks"]


class Tracer:
    """Triangles in Embree, recentred in float64 before the cast to float32.

    Parameters
    ----------
    positions : (n, 3) float64
    faces : (m, 3) int64
    robust : bool
        Embree's robust traversal (watertight at shared edges; slower).
    recentred : bool
        The positions are already in their local frame (``center`` is then 0).

    Notes
    -----
    Embree is single precision. A mesh 1e4 units from the origin has float32 spacing
    of ~1e-3 there, enough to move vertices by more than any sensible ray offset;
    subtracting the bounding-box centre in float64 first keeps full precision relative
    to the mesh's own size, so AO does not depend on where the mesh is.
    """

    def __init__(
        self,
        positions: FloatArray,
        faces: IndexArray,
        *,
        robust: bool = False,
        recentred: bool = False,
    ):
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        positions = np.asarray(positions, dtype=np.float64)
        lo, hi = positions.min(axis=0), positions.max(axis=0)
        self.center = np.zeros(3) if recentred else 0.5 * (lo + hi)
        self.local = positions - self.center
        #: Largest recentred coordinate: the magnitude that sets float32 rounding.
        self.magnitude = float(np.abs(self.local).max())
        if faces.size and faces.max() > np.iinfo(np.int32).max:
            raise InputError(None, f"{faces.max()} vertices exceed Embree's 32-bit indices")
        self._scene = rtcore_scene.EmbreeScene(robust=robust)
        TriangleMesh(self._scene, self.local.astype(np.float32), faces.astype(np.int32))
        # Commit now, on this thread: EmbreeScene.run commits lazily and is not safe to
        # commit from two worker threads at once.
        probe = np.zeros((1, 3), dtype=np.float32)
        self._scene.run(probe, np.array([[0, 0, 1]], dtype=np.float32), query="OCCLUDED")

    def occluded(self, origins, directions, tfar: float = INFINITE_DISTANCE) -> np.ndarray:
        """(k,) int32: 0 where a ray (float32 arrays, local frame) hits within ``tfar``, -1 else."""
        return self._scene.run(origins, directions, dists=float(tfar), query="OCCLUDED")

    def intersect(self, origins, directions, tfar: np.ndarray) -> dict:
        """Closest hits: dict with ``primID`` (k,) int32 (-1 = miss), ``tfar``, ``Ng`` (k, 3)."""
        return self._scene.run(
            origins,
            directions,
            dists=np.ascontiguousarray(tfar, dtype=np.float32),
            query="INTERSECT",
            output=True,
        )


def split(items: np.ndarray, per_chunk: int) -> list[np.ndarray]:
    """``items`` in consecutive chunks of at most ``per_chunk`` (>= 1)."""
    per_chunk = max(1, int(per_chunk))
    return [items[s : s + per_chunk] for s in range(0, items.shape[0], per_chunk)]


def trace_chunks(
    chunks: Sequence,
    work: Callable[[object], int],
    *,
    threads: int,
    progress: Progress,
    pool: ThreadPoolExecutor | None = None,
) -> None:
    """``work(chunk)`` for every chunk on ``threads`` worker threads (embreex releases the
    GIL while it traces); ``progress`` advances by what each returns, in chunk order.

    Each chunk must write only its own output slots, so the result does not depend on
    the thread count or the chunking. On Ctrl-C or any error the queued chunks are
    dropped instead of traced. ``pool``: an executor to reuse across calls (it is then
    left running).
    """
    own = pool is None
    pool = ThreadPoolExecutor(max_workers=max(1, int(threads))) if own else pool
    futures = []
    try:  # queueing many chunks takes a while: a Ctrl-C then must drop them too
        futures.extend(pool.submit(work, chunk) for chunk in chunks)
        for future in futures:
            progress.advance(future.result())
    finally:
        for future in futures:
            future.cancel()
        if own:
            pool.shutdown(wait=True, cancel_futures=True)
