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
    "start_scene",
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
    deferred : bool
        Do not build the Embree scene yet (:meth:`build`).

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
        deferred: bool = False,
    ):
        self._positions = positions = np.asarray(positions, dtype=np.float64)
        lo, hi = positions.min(axis=0), positions.max(axis=0)
        self.center = np.zeros(3) if recentred else 0.5 * (lo + hi)
        #: Largest recentred coordinate: the magnitude that sets float32 rounding. The
        #: extremes of ``local`` are ``lo - center`` and ``hi - center`` (rounding is
        #: monotonic), so no recentred copy is made for it.
        self.magnitude = float(np.maximum(np.abs(lo - self.center), np.abs(hi - self.center)).max())
        #: Power of two the recentred coordinates are divided by before the cast.
        self.scale = power_of_two_scale(self.magnitude)
        if faces.size and faces.max() > np.iinfo(np.int32).max:
            raise InputError(None, f"{faces.max()} vertices exceed Embree's 32-bit indices")
        self._faces, self._robust, self._embree = faces, robust, None
        self._building: tuple | None = None  # (thread, scene, outcome) of a background build
        if not deferred:
            self.build()

    def build(self, *, background: bool = False) -> Tracer:
        """Hand the triangles to Embree and build its BVH, once. A tracer made with
        ``deferred=True`` (its frame known, :attr:`local` and :meth:`frame` usable)
        answers queries only after this, so a caller can free what it prepared from the
        frame before Embree's memory (~170 bytes per vertex) is taken.

        ``background=True``: the triangles are handed over now and Embree builds the BVH
        on a thread of its own, the GIL released, while the caller goes on; the first
        query, or ``build()``, waits for it (the same BVH either way). Where the build
        cannot be started that way it is done now."""
        if self._embree is not None:
            return self
        if self._building is not None:
            return self._join()
        from embreex import rtcore, rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        device = rtcore.EmbreeDevice()
        scene = rtcore_scene.EmbreeScene(device, robust=self._robust)
        uploaded = _upload(scene, device, self._positions, self.center, self.scale, self._faces)
        if not uploaded:
            TriangleMesh(scene, self.frame(self.local), self._faces.astype(np.int32))
        self._faces = None
        if background and uploaded:
            outcome: list = []
            thread = threading.Thread(target=_commit, args=(scene, device, outcome), name="embree-build")
            self._building = (thread, scene, outcome)
            thread.start()
            return self
        # Commit now, on this thread: EmbreeScene.run commits lazily and is not safe to
        # commit from two worker threads at once.
        probe = np.zeros((1, 3), dtype=np.float32)
        scene.run(probe, np.array([[0, 0, 1]], dtype=np.float32), query="OCCLUDED")
        self._embree = scene
        return self

    def _join(self) -> Tracer:
        """Wait for a background build (:meth:`build`); its error, if any, raised here."""
        thread, scene, outcome = self._building
        thread.join()
        self._building = None
        if outcome:
            raise outcome[0]
        self._embree = scene
        return self

    @property
    def _scene(self):
        if self._embree is None:
            if self._building is not None:
                return self._join()._embree
            raise RuntimeError("Tracer(deferred=True) traces only after build()")
        return self._embree

    @property
    def local(self) -> np.ndarray:
        """(n, 3) float64: the positions minus ``center``, made on each access (not kept:
        24 bytes per vertex)."""
        return self._positions - self.center

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
def shared_scenes(started: Iterable = ()):
    """Within the block (on this thread), :func:`tracer_for` builds one :class:`Tracer`
    per pair of arrays and hands the same one out again: a lit bake's light pass traces
    the Embree scene its AO pass built. The arrays must not change inside the block.
    ``started``: ``(positions, faces, tracer)`` made beforehand (:func:`start_scene`),
    handed out for those arrays."""
    outer = getattr(_shared, "scenes", None)
    if outer is None:
        _shared.scenes = []
    _shared.scenes.extend(started)
    try:
        yield
    finally:
        if outer is None:
            _shared.scenes = None


def start_scene(positions: FloatArray, faces: IndexArray) -> tuple:
    """``(positions, faces, tracer)``: a :class:`Tracer` whose BVH Embree builds in the
    background from now (:meth:`Tracer.build`), for :func:`shared_scenes`."""
    return positions, faces, Tracer(positions, faces, deferred=True).build(background=True)


def tracer_for(positions: FloatArray, faces: IndexArray, *, deferred: bool = False) -> Tracer:
    """``Tracer(positions, faces, deferred=deferred)``, or inside :func:`shared_scenes`
    the one already made for these very array objects (built unless ``deferred``)."""
    scenes = getattr(_shared, "scenes", None)
    if scenes is None:
        return Tracer(positions, faces, deferred=deferred)
    for p, f, tracer in scenes:
        if p is positions and f is faces:
            return tracer if deferred else tracer.build()
    tracer = Tracer(positions, faces, deferred=deferred)
    scenes.append((positions, faces, tracer))
    return tracer


#: Embree 4's C enums (rtcore_common.h, rtcore_geometry.h).
_GEOMETRY_TRIANGLE, _BUFFER_INDEX, _BUFFER_VERTEX = 0, 0, 1
_FORMAT_UINT3, _FORMAT_FLOAT3 = 0x5003, 0x9003
_api = None
_BLOCK = 1 << 16  # rows per block of the vertex upload


def _embree_api():
    """Embree's C functions through ctypes, or False where embreex's objects are not laid
    out as this module expects (another embreex build): :func:`_upload` then declines.

    embreex's ``TriangleMesh`` copies the arrays into Embree's buffers one Python item at
    a time (~1 s per million triangles); these calls let numpy fill the same buffers.
    The handles are read from embreex's objects: ``EmbreeScene`` holds its ``RTCScene``
    right after the object header, then ``is_committed``, then its ``EmbreeDevice``,
    which holds its ``RTCDevice`` right after its header. Both are checked on a probe
    scene (object sizes, a sentinel written through the public ``is_committed``, the
    device's address) before use.
    """
    global _api
    if _api is None:
        _api = False
        try:
            import ctypes

            from embreex import rtcore, rtcore_scene

            word = ctypes.sizeof(ctypes.c_void_p)
            head = object.__basicsize__
            if (rtcore_scene.EmbreeScene.__basicsize__, rtcore.EmbreeDevice.__basicsize__) != (
                head + 3 * word,
                head + word,
            ):
                return _api
            device = rtcore.EmbreeDevice()
            probe = rtcore_scene.EmbreeScene(device, robust=False)
            probe.is_committed = 0x5A17
            if (
                ctypes.c_int.from_address(id(probe) + head + word).value != 0x5A17
                or ctypes.c_void_p.from_address(id(probe) + head + 2 * word).value != id(device)
            ):
                return _api
            probe.is_committed = 0
            lib = ctypes.CDLL(rtcore_scene.__file__)  # its symbols and libembree's
            vp, size, uint, enum = ctypes.c_void_p, ctypes.c_size_t, ctypes.c_uint, ctypes.c_int
            for name, res, args in (
                ("rtcNewGeometry", vp, [vp, enum]),
                ("rtcSetNewGeometryBuffer", vp, [vp, enum, uint, enum, size, size]),
                ("rtcCommitGeometry", None, [vp]),
                ("rtcAttachGeometry", uint, [vp, vp]),
                ("rtcReleaseGeometry", None, [vp]),
                ("rtcCommitScene", None, [vp]),
                ("rtcGetDeviceError", enum, [vp]),
            ):
                fn = getattr(lib, name)
                fn.restype, fn.argtypes = res, args
            _api = (lib, head, word)
        except (ImportError, OSError, AttributeError, ValueError):
            _api = False
    return _api


def _upload(scene, device, positions: np.ndarray, center, scale: float, faces: np.ndarray) -> bool:
    """Fill a fresh embreex scene (made on ``device``) with the triangles, vertices
    ``(positions - center) / scale`` cast to float32 (the values ``TriangleMesh`` would
    copy), through Embree's own buffers; False where :func:`_embree_api` declines (the
    caller then uses ``TriangleMesh``)."""
    import ctypes

    api = _embree_api()
    if not api:
        return False
    lib, head, word = api
    if ctypes.c_void_p.from_address(id(scene) + head + 2 * word).value != id(device):
        return False
    scene_ptr = ctypes.c_void_p.from_address(id(scene) + head).value
    device_ptr = ctypes.c_void_p.from_address(id(device) + head).value
    geom = lib.rtcNewGeometry(device_ptr, _GEOMETRY_TRIANGLE)
    if not geom:
        return False
    try:
        n, m = positions.shape[0], faces.shape[0]
        vbuf = lib.rtcSetNewGeometryBuffer(geom, _BUFFER_VERTEX, 0, _FORMAT_FLOAT3, 16, n)
        ibuf = lib.rtcSetNewGeometryBuffer(geom, _BUFFER_INDEX, 0, _FORMAT_UINT3, 12, m)
        if (n and not vbuf) or (m and not ibuf):
            raise MemoryError(f"Embree could not allocate buffers for {n} vertices and {m} triangles")
        if n:
            v = np.ctypeslib.as_array((ctypes.c_float * (4 * n)).from_address(vbuf)).reshape(n, 4)
            for a in range(0, n, _BLOCK):  # in blocks: no full-size float64 temporary
                b = min(a + _BLOCK, n)
                v[a:b, :3] = (positions[a:b] - center) / scale
            v[:, 3] = 0.0
        if m:
            t = np.ctypeslib.as_array((ctypes.c_uint32 * (3 * m)).from_address(ibuf)).reshape(m, 3)
            t[...] = faces
        lib.rtcCommitGeometry(geom)
        lib.rtcAttachGeometry(scene_ptr, geom)
    finally:
        lib.rtcReleaseGeometry(geom)
    if lib.rtcGetDeviceError(device_ptr) != 0:
        raise MemoryError("Embree could not take the triangles (out of memory?)")
    return True


def _commit(scene, device, outcome: list) -> None:
    """Build the BVH of a scene :func:`_upload` filled (``rtcCommitScene`` through ctypes,
    which releases the GIL) and mark it committed for embreex; an error is appended to
    ``outcome`` for :meth:`Tracer.build` to raise."""
    import ctypes

    try:
        lib, head, _ = _embree_api()
        lib.rtcCommitScene(ctypes.c_void_p.from_address(id(scene) + head).value)
        if lib.rtcGetDeviceError(ctypes.c_void_p.from_address(id(device) + head).value) != 0:
            raise MemoryError("Embree could not build its scene (out of memory?)")
        scene.is_committed = 1  # what EmbreeScene.run sets once it has committed
    except BaseException as exc:  # raised again on the caller's thread
        outcome.append(exc)


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
