"""Every ORB-SLAM3 run in its own child process, so that a crash or a hang costs that run only.

ORB-SLAM3 is C++ with its own threads: a segfault, an abort or a deadlock inside it would end
or freeze the evaluating process, and with it a whole ``slam-eval`` batch, a sweep or the
demo. :func:`run_orbslam3_isolated` starts a child (``multiprocessing``'s ``forkserver``: a
fork of a clean server process that imported slimseg and the engine once, so nothing of the
evaluating process's threads or locks is inherited; ``spawn`` where there is no forkserver,
e.g. Windows), which tracks the
frames with :func:`~slimseg.slam.engines.run_orbslam3` and sends back plain data (trajectory
array, state names, timings). A child killed by a signal, one that outlives its timeout (it is
killed), or one whose engine raised, comes back as a :class:`RunFailure` naming the cause. The
fork server itself may die (the OOM killer picks the largest process): the run it was to
serve fails and the next run starts a fresh server (:func:`start_child`).

Frames travel through shared memory, packed once per condition by :class:`SharedFrames`
(``rgb uint8 [N, H, W, 3]``, ``depth float32 [N, H, W]``, ``stamp float64 [N]``): every run of
the condition maps the same block instead of receiving a copy through a pipe.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import time
from collections.abc import Sequence
from dataclasses import dataclass
from multiprocessing import forkserver, get_all_start_methods, get_context, shared_memory
from multiprocessing.connection import Connection
from multiprocessing.context import BaseContext
from multiprocessing.process import BaseProcess
from pathlib import Path

import numpy as np

from slimseg.errors import SlimsegError
from slimseg.slam.engines import EngineFrame, EngineRun, run_orbslam3

log = logging.getLogger(__name__)

MIN_TIMEOUT_S = 120.0
"""vocabulary loading (ORBvoc.txt, text: tens of seconds on a slow machine) and start-up"""
TIMEOUT_PER_SEQUENCE_S = 10.0
"""budget per second of sequence replayed: ten times the live rate"""
EXIT_GRACE_S = 30.0  # after sending its result, a child gets this long to exit on its own
FAULT_ENV = "SLIMSEG_ENGINE_FAULT"
"""fault injection for tests: ``<run>=<SIGNAL|hang>@<frame>[,...]``, e.g. ``2=SIGSEGV@5``
makes the child of run 2 raise SIGSEGV on itself when the engine reads frame 5 (0-based)"""


@dataclass(frozen=True)
class RunFailure:
    """A run that returned nothing: ``reason`` as reports show it (``engine crashed
    (SIGSEGV)``, ``engine timed out after 60 s (killed)``, ``engine error: …``)."""

    reason: str


def default_timeout(frames: int, fps: float, realtime: bool, speed: float) -> float:
    """Seconds a run of ``frames`` may take: :data:`MIN_TIMEOUT_S` plus
    :data:`TIMEOUT_PER_SEQUENCE_S` per second of sequence at its replay rate."""
    replay_s = frames / max(fps, 1e-3) / (speed if realtime else 1.0)
    return MIN_TIMEOUT_S + TIMEOUT_PER_SEQUENCE_S * replay_s


_FIELDS = ("rgb", "depth", "stamp")
SHM_DIR = Path("/dev/shm")
SHM_HEADROOM = 0.8  # use at most this share of /dev/shm's free space (containers: often 64 MB)
Spec = dict[str, tuple[str, str, tuple[int, ...], str]]
"""per field: ``("shm", block name | "file", .npy path, shape, dtype)``"""


class SharedFrames:
    """One condition's frames where every run's child can map them (see the module
    docstring): POSIX shared memory, or, when ``/dev/shm`` has not the room (a container's
    default is 64 MB), ``.npy`` files in ``spill`` (deleted on :meth:`close`). A context
    manager. All frames must have the same size."""

    def __init__(self, frames: Sequence[EngineFrame], spill: Path) -> None:
        if not frames:
            raise SlimsegError("no frames to track")
        n, (h, w) = len(frames), frames[0].rgb.shape[:2]
        layout = {"rgb": ((n, h, w, 3), np.uint8), "depth": ((n, h, w), np.float32),
                  "stamp": ((n,), np.float64)}  # fmt: skip
        total = sum(int(np.prod(shape)) * np.dtype(t).itemsize for shape, t in layout.values())
        in_memory = _shm_room() >= total
        self.spec: Spec = {}
        self._blocks: list[shared_memory.SharedMemory] = []
        self._files: list[Path] = []
        try:
            for key, (shape, dtype) in layout.items():
                target = self._allocate(key, shape, np.dtype(dtype), in_memory, spill)
                for i, f in enumerate(frames):  # filled in place: no stacked copy
                    target[i] = (f.rgb, f.depth_m, f.stamp)[_FIELDS.index(key)]
                del target
        except BaseException:
            self.close()
            raise

    def _allocate(
        self, key: str, shape: tuple[int, ...], dtype: np.dtype, in_memory: bool, spill: Path
    ) -> np.ndarray:
        if in_memory:
            nbytes = int(np.prod(shape)) * dtype.itemsize
            block = shared_memory.SharedMemory(create=True, size=max(nbytes, 1))
            self._blocks.append(block)
            self.spec[key] = ("shm", block.name, shape, dtype.str)
            return np.ndarray(shape, dtype, buffer=block.buf)
        path = spill / f".frames.{os.getpid()}.{key}.npy"
        self._files.append(path)
        self.spec[key] = ("file", str(path), shape, dtype.str)
        return np.lib.format.open_memmap(path, mode="w+", dtype=dtype, shape=shape)

    def __len__(self) -> int:
        return self.spec["stamp"][2][0]

    def close(self) -> None:
        """Free the blocks and delete the files (children that still map them keep their
        mapping)."""
        for block in self._blocks:
            block.close()
            block.unlink()
        for path in self._files:
            path.unlink(missing_ok=True)
        self._blocks, self._files = [], []

    def __enter__(self) -> SharedFrames:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def run_orbslam3_isolated(
    frames: SharedFrames,
    vocab: Path,
    settings: Path,
    realtime: bool,
    log_path: Path,
    speed: float,
    timeout_s: float,
    run: int = 1,
) -> EngineRun | RunFailure:
    """:func:`~slimseg.slam.engines.run_orbslam3` on ``frames`` in a child process; run
    number ``run`` (1-based) names it in the log and in :data:`FAULT_ENV`."""
    ctx = _context()
    recv, send = ctx.Pipe(duplex=False)
    args = (frames.spec, str(vocab), str(settings), realtime, str(log_path), speed,
            _fault(run), send)  # fmt: skip
    t0 = time.perf_counter()
    try:
        child = start_child(ctx, _child, args, f"orbslam3-run{run}")
    except ServerDied as e:
        send.close()
        recv.close()
        log.warning("ORB-SLAM3 run %d: %s", run, e)
        return RunFailure(str(e))
    send.close()  # the child holds the only writer: its death reads as EOF here
    try:
        msg = _receive(recv, timeout_s)
    except BaseException:  # Ctrl-C while waiting: the run goes with the caller
        child.kill()
        child.join()
        raise
    finally:
        recv.close()
    if msg is _TIMEOUT:
        child.kill()
        child.join()
        return RunFailure(f"engine timed out after {timeout_s:g} s (killed)")
    child.join(EXIT_GRACE_S)
    if child.is_alive():  # it closed its pipe but does not exit: stuck in shutdown
        child.kill()
        child.join()
        log.warning("ORB-SLAM3 run %d hung on exit and was killed (its result is kept)", run)
    log.debug("ORB-SLAM3 run %d: child process %.2f s", run, time.perf_counter() - t0)
    if msg is None:
        return RunFailure(f"engine crashed ({_exit_reason(child.exitcode)})")
    if msg[0] == "error":
        return RunFailure(f"engine error: {msg[1]}")
    _, trajectory, states, ms, late = msg
    return EngineRun(np.asarray(trajectory, np.float64).reshape(-1, 8), list(states), ms, late)


_TIMEOUT = ("timeout",)
_PRELOAD = ["slimseg.slam.engine_process", "pyorbslam3"]


def _context() -> BaseContext:
    """``forkserver`` where the platform has it (a clean single-threaded server that imported
    this module and the engine once; each run is a fork of it: tens of ms), else ``spawn``
    (a fresh interpreter per run)."""
    if "forkserver" not in get_all_start_methods():
        return get_context("spawn")
    ctx = get_context("forkserver")
    ctx.set_forkserver_preload(_PRELOAD)  # read when the server starts (first run)
    return ctx


class ServerDied(Exception):
    """The fork server was gone when a run was to start (the kernel's OOM killer picks the
    largest process, and the server holds the engine and its vocabulary)."""


def start_child(ctx: BaseContext, target: object, args: tuple, name: str) -> BaseProcess:
    """Start ``target(*args)`` in a daemon child of ``ctx``. When the fork server died (its
    socket refuses, or closes before the child's pid arrives), it is cleared so that the next
    start launches a fresh one, and :class:`ServerDied` is raised: the run it was to serve
    fails, the batch goes on."""
    child = ctx.Process(target=target, args=args, name=name, daemon=True)
    try:
        child.start()
    except (OSError, EOFError) as e:
        if ctx.get_start_method() != "forkserver":
            raise
        _clear_fork_server()
        raise ServerDied(
            f"the engines' fork server died ({type(e).__name__}: {e}); this run failed, the "
            "next one starts a fresh server"
        ) from None
    return child


def _clear_fork_server() -> None:
    """Forget a dead fork server so that ``ensure_running`` launches a new one. Python keeps
    the server in ``multiprocessing.forkserver._forkserver`` and relaunches it only when its
    ``waitpid`` sees it gone; a server killed mid-request can look alive there, so it is
    killed for sure, reaped, and its state cleared (the attributes CPython 3.9-3.13 use)."""
    server = forkserver._forkserver
    with server._lock:
        pid, alive_fd = server._forkserver_pid, server._forkserver_alive_fd
        if pid is not None:
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)
            with contextlib.suppress(ChildProcessError):
                os.waitpid(pid, 0)
        if alive_fd is not None:
            with contextlib.suppress(OSError):
                os.close(alive_fd)
        server._forkserver_pid = None
        server._forkserver_alive_fd = None
        server._forkserver_address = None


def _receive(recv: Connection, timeout_s: float) -> tuple | None:
    """The child's message; None when it died first (EOF), :data:`_TIMEOUT` when it sent
    nothing within ``timeout_s``."""
    if not recv.poll(timeout_s):
        return _TIMEOUT
    try:
        return recv.recv()
    except EOFError:
        return None


def _exit_reason(code: int | None) -> str:
    if code is not None and code < 0:
        try:
            return signal.Signals(-code).name
        except ValueError:
            return f"signal {-code}"
    return f"exit code {code} without a result"


def _shm_room() -> int:
    """Bytes of ``/dev/shm`` this may use (:data:`SHM_HEADROOM` of its free space); where
    there is no ``/dev/shm`` (macOS, Windows), shared memory is not size-limited that way."""
    if not SHM_DIR.is_dir():
        return 1 << 62
    st = os.statvfs(SHM_DIR)
    return int(SHM_HEADROOM * st.f_bavail * st.f_frsize)


def _fault(run: int) -> str | None:
    """This run's entry of :data:`FAULT_ENV` (``SIGNAL@frame`` or ``hang@frame``), if any."""
    for item in os.environ.get(FAULT_ENV, "").split(","):
        key, _, value = item.partition("=")
        if key.strip() == str(run):
            return value.strip()
    return None


def _child(
    spec: Spec,
    vocab: str,
    settings: str,
    realtime: bool,
    log_path: str,
    speed: float,
    fault: str | None,
    send: Connection,
) -> None:
    """The child's body: map the frames, track, send ``("ok", trajectory, states, ms, late)``
    or ``("error", message)``."""
    blocks, arrays = [], []  # the blocks stay referenced while their arrays are in use
    for k in _FIELDS:
        kind, ref, shape, dtype = spec[k]
        if kind == "shm":
            blocks.append(shared_memory.SharedMemory(name=ref))
            arrays.append(np.ndarray(shape, np.dtype(dtype), buffer=blocks[-1].buf))
        else:
            arrays.append(np.load(ref, mmap_mode="c", allow_pickle=False))  # writable view
    rgb, depth, stamp = arrays
    try:
        frames: list = [EngineFrame(rgb[i], depth[i], float(stamp[i])) for i in range(len(stamp))]
        if fault:
            frames = _inject(frames, fault)
        try:
            run = run_orbslam3(frames, Path(vocab), Path(settings), realtime, Path(log_path),
                               speed=speed)  # fmt: skip
            msg: tuple = ("ok", run.trajectory, run.states, run.ms_per_frame, run.late)
        except Exception as e:  # any engine error: this run fails, not the batch
            msg = ("error", str(e) if isinstance(e, SlimsegError) else f"{type(e).__name__}: {e}")
        send.send(msg)
    finally:
        send.close()


class _FaultyFrame:
    """A frame that raises a signal on this process (``SIGNAL``) or never returns (``hang``)
    when the engine reads its pixels: a real failure in the middle of tracking."""

    def __init__(self, frame: EngineFrame, what: str) -> None:
        self.depth_m, self.stamp, self.static = frame.depth_m, frame.stamp, frame.static
        self._rgb, self._what = frame.rgb, what

    @property
    def rgb(self) -> np.ndarray:
        if self._what == "hang":
            while True:
                time.sleep(1)
        os.kill(os.getpid(), signal.Signals[self._what])
        return self._rgb


def _inject(frames: list[EngineFrame], fault: str) -> list:
    """``frames`` with frame ``k`` of ``SIGNAL@k`` / ``hang@k`` replaced by a faulty one."""
    what, _, at = fault.partition("@")
    k = min(int(at or 0), len(frames) - 1)
    return [*frames[:k], _FaultyFrame(frames[k], what), *frames[k + 1 :]]
