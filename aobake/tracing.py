"""The Embree boundary: triangles recentred and scaled by a power of two in float64, then
cast to float32, and the one chunked, thread-pooled loop every ray caster uses.

The only module that imports embreex. Knows nothing about the methods that call it;
the word "scene" is kept for what a file holds.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

import numpy as np

from ._types import FloatArray, IndexArray
from .constants import INFINITE_DISTANCE
from .errors import InputError
from .progress import Progress

__all__ = [
    "INFINITE_DISTANCE",
    "Tracer",
    "power_of_two_scale",
    "shared_scenes",
    "split",
    "trace_chunks",
    "tracer_for",
]


class Tracer:
    """Triangles in Embree, recentred and normalised in float64 before the cast to float32.

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
    to the mesh's own size, so AO does not depend on where the mesh is. Embree also
    misses hits on meshes larger than ~1e13 or smaller than ~1e-13 units (its
    constants and float32 products leave their range), so the recentred coordinates
    are divided by ``scale``, the power of two that brings the largest into [0.5, 1):
    exact, so AO does not depend on the mesh's size either. Points and distances go in
    and out in mesh units (recentred); :meth:`frame` gives the float32 points Embree
    takes.
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
        #: Power of two the recentred coordinates are divided by before the cast.
        self.scale = power_of_two_scale(self.magnitude)
        if faces.size and faces.max() > np.iinfo(np.int32).max:
            raise InputError(None, f"{faces.max()} vertices exceed Embree's 32-bit indices")
        self._scene = rtcore_scene.EmbreeScene(robust=robust)
        TriangleMesh(self._scene, self.frame(self.local), faces.astype(np.int32))
        # Commit now, on this thread: EmbreeScene.run commits lazily and is not safe to
        # commit from two worker threads at once.
        probe = np.zeros((1, 3), dtype=np.float32)
        self._scene.run(probe, np.array([[0, 0, 1]], dtype=np.float32), query="OCCLUDED")

    def frame(self, points: FloatArray) -> np.ndarray:
        """Recentred points (mesh units, float64) as the float32 points Embree takes."""
        return np.ascontiguousarray(np.asarray(points, dtype=np.float64) / self.scale, dtype=np.float32)

    def _dists(self, tfar):
        """Mesh-unit ray lengths in Embree's frame; None = unbounded (INFINITE_DISTANCE)."""
        if tfar is None:
            return INFINITE_DISTANCE
        return np.minimum(np.asarray(tfar, dtype=np.float64) / self.scale, INFINITE_DISTANCE)

    def occluded(self, origins, directions, tfar: float | None = None) -> np.ndarray:
        """(k,) int32: 0 where a ray hits within ``tfar`` (mesh units; None: unbounded),
        -1 else. ``origins``: float32 in Embree's frame (:meth:`frame`); ``directions``:
        float32."""
        return self._scene.run(origins, directions, dists=float(self._dists(tfar)), query="OCCLUDED")

    def occluded_within(self, origins, directions, dists: np.ndarray) -> np.ndarray:
        """:meth:`occluded` with per-ray lengths ``dists`` (k,) float32 already in Embree's
        frame (mesh units / ``scale``, at most ``INFINITE_DISTANCE``), as kernels make them."""
        return self._scene.run(origins, directions, dists=dists, query="OCCLUDED")

    def first_hits(self, origins, directions, tfar: float | None = None) -> np.ndarray:
        """(k,) int32: the triangle each ray hits first within ``tfar`` (mesh units;
        None: unbounded), -1 for none; ``origins`` as for :meth:`occluded`."""
        return self._scene.run(origins, directions, dists=float(self._dists(tfar)), query="INTERSECT")

    def first_hits_within(self, origins, directions, dists: np.ndarray) -> np.ndarray:
        """:meth:`first_hits` with per-ray lengths ``dists`` in Embree's frame, as for
        :meth:`occluded_within`."""
        return self._scene.run(origins, directions, dists=dists, query="INTERSECT")

    def intersect(self, origins, directions, tfar: np.ndarray) -> dict:
        """Closest hits: dict with ``primID`` (k,) int32 (-1 = miss), ``tfar`` (mesh
        units, float64), ``Ng`` (k, 3); ``origins`` as for :meth:`occluded`."""
        hit = self._scene.run(
            origins,
            directions,
            dists=np.ascontiguousarray(self._dists(tfar), dtype=np.float32),
            query="INTERSECT",
            output=True,
        )
        hit["tfar"] = hit["tfar"].astype(np.float64) * self.scale
        return hit


_shared = threading.local()


@contextmanager
def shared_scenes():
    """Within the block (on this thread), :func:`tracer_for` builds one :class:`Tracer`
    per pair of arrays and hands the same one out again: a lit bake's light pass traces
    the Embree scene its AO pass built. The arrays must not change inside the block."""
    outer = getattr(_shared, "scenes", None)
    if outer is None:
        _shared.scenes = []
    try:
        yield
    finally:
        if outer is None:
            _shared.scenes = None


def tracer_for(positions: FloatArray, faces: IndexArray) -> Tracer:
    """``Tracer(positions, faces)``, or inside :func:`shared_scenes` the one already built
    for these very array objects."""
    scenes = getattr(_shared, "scenes", None)
    if scenes is None:
        return Tracer(positions, faces)
    for p, f, tracer in scenes:
        if p is positions and f is faces:
            return tracer
    tracer = Tracer(positions, faces)
    scenes.append((positions, faces, tracer))
    return tracer


def power_of_two_scale(magnitude: float) -> float:
    """2**e with ``magnitude / 2**e`` in [0.5, 1) (1.0 for zero or non-finite magnitudes).

    Dividing by a power of two is exact in floating point, so the normalised scene is
    the same scene bit for bit, only its exponents shifted.
    """
    if not (magnitude > 0.0 and math.isfinite(magnitude)):
        return 1.0
    return math.ldexp(1.0, math.frexp(magnitude)[1])


def split(items: np.ndarray, per_chunk: int) -> list[np.ndarray]:
    """``items`` in consecutive chunks of at most ``per_chunk`` (>= 1)."""
    per_chunk = max(1, int(per_chunk))
    return [items[s : s + per_chunk] for s in range(0, items.shape[0], per_chunk)]


def trace_chunks(
    chunks: Iterable,
    work: Callable[[object], int],
    *,
    threads: int,
    progress: Progress,
    pool: ThreadPoolExecutor | None = None,
) -> None:
    """``work(chunk)`` for every chunk on ``threads`` worker threads (embreex releases the
    GIL while it traces); ``progress`` advances by what each returns, in chunk order.

    Each chunk must write only its own output slots (or add integers under a lock), so
    the result does not depend on the thread count or the chunking. ``chunks`` may be a
    generator: at most ``4 * threads`` are queued at a time, so memory stays bounded
    however many there are. On Ctrl-C or any error the queued chunks are dropped
    instead of traced. ``pool``: an executor to reuse across calls (it is then left
    running).
    """
    threads = max(1, int(threads))
    own = pool is None
    pool = ThreadPoolExecutor(max_workers=threads) if own else pool
    window: deque = deque()
    try:
        for chunk in chunks:
            window.append(pool.submit(work, chunk))
            if len(window) >= 4 * threads:
                progress.advance(window.popleft().result())
        while window:
            progress.advance(window.popleft().result())
    finally:
        for future in window:
            future.cancel()
        if own:
            pool.shutdown(wait=True, cancel_futures=True)
