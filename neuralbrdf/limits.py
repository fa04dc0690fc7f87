"""Resource limits for files read from users (docs/robustness.md): sizes are checked before allocation.

A file from elsewhere must not be able to make the process read or allocate without bound.  Each
reader checks the size a file *claims* (its length on disk, the shapes in its header, the
hyper-parameters of a checkpoint) against these limits before it reads or builds anything, and
refuses with an :class:`~neuralbrdf.errors.InputError` naming the file, the size and the limit.
The limits sit far above anything the project writes (noted beside each).
"""

from __future__ import annotations

import errno
import os
import stat

from neuralbrdf.errors import InputError

MIB = 2**20

#: CSV files (BRDF tables, GCMS raw files).  The largest the project writes, a spectral table on
#: the Löw et al. plan (230 400 rows × 35 columns), is about 150 MiB.
MAX_CSV_BYTES = 512 * MIB
#: Mitsuba ``tensor_file`` measurements (RGL ``.bsdf``).  The RGL database's spectral files are
#: about 7 MiB (195 wavelengths), its anisotropic ones a few times that.
MAX_TENSOR_FILE_BYTES = 256 * MIB
#: Header quantities of a ``tensor_file``, each bounded before anything is allocated for it: the
#: RGL's files have 11 fields of rank at most 5 with names of a dozen bytes.
MAX_TENSOR_FIELDS = 1024
MAX_TENSOR_RANK = 16
MAX_TENSOR_NAME_BYTES = 256
#: ``.onnx`` model files.  A paper-size NLB (1.07 M weights) is about 4 MiB.
MAX_ONNX_BYTES = 256 * MIB
#: Total elements of an ONNX graph's initialisers and constants (as declared by their shapes).
MAX_ONNX_WEIGHT_ELEMENTS = 64 * MIB
#: PyTorch checkpoints (``.ckpt``).  The paper-size NLB pretraining checkpoint is about 13 MiB.
MAX_CHECKPOINT_BYTES = 1024 * MIB
#: Parameters a checkpoint's hyper-parameters may ask for (checked on the meta device, before
#: anything is allocated).  The paper-size NLB has 1.07 M.
MAX_MODEL_PARAMETERS = 64 * MIB
#: NBRDF architecture files (Keras ``.json``), a few KiB each.
MAX_JSON_BYTES = 16 * MIB
#: Multiply-adds of one network evaluation that the ``drjit`` render backend unrolls into its
#: kernel.  The spectral MLP has about 250, the compact NLB about 14 000; a paper-size NLB
#: (~1 M) compiles for minutes and takes many GB, so above this the backend refuses and the
#: render command falls back to ``onnxruntime`` with a message.
DRJIT_MAX_MULTIPLY_ADDS = 100_000


def file_problem(path: str | os.PathLike[str]) -> str | None:
    """Why ``path``, which is there in some form, cannot be read as a regular file: a FIFO, device
    or socket (read without end), a directory, a symbolic link that loops or points nowhere, a path
    the system refuses; ``None`` for a regular file or nothing at all (each reader says "no such
    file" in its own words)."""
    try:
        info = os.stat(path)
    except ValueError:
        return None
    except OSError as error:
        if error.errno == errno.ELOOP:
            return "is a symbolic link that loops (too many levels of symbolic links)"
        if error.errno == errno.ENOENT:
            return f"is a broken symbolic link (to {os.readlink(path)!r})" if os.path.islink(path) else None
        return f"cannot be read: {os.strerror(error.errno).lower()}" if error.errno else None
    if stat.S_ISDIR(info.st_mode):
        return "is a directory, not a file"
    if not stat.S_ISREG(info.st_mode):
        kind = "a FIFO" if stat.S_ISFIFO(info.st_mode) else "a socket" if stat.S_ISSOCK(info.st_mode) else "a device"
        return f"is {kind}, not a regular file"
    return None


def check_file_size(path: str | os.PathLike[str], limit_bytes: int, what: str) -> int:
    """The size of ``path`` in bytes, or :class:`InputError` if it exceeds ``limit_bytes`` or is
    not a regular file (:func:`file_problem`; a directory or nothing at all is left to the reader)."""
    problem = file_problem(path)
    if problem is not None and not os.path.isdir(path):
        raise InputError(f"{problem}; expected a {what}", path=path)
    try:
        size = os.stat(path).st_size
    except (OSError, ValueError):
        return 0  # the reader reports a missing file in its own words
    if size > limit_bytes:
        raise InputError(
            f"{what} of {size / MIB:.1f} MiB exceeds the limit of {limit_bytes / MIB:.0f} MiB "
            "(neuralbrdf.limits); refusing to read it",
            path=path,
        )
    return size
