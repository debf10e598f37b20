"""Trajectory files: never overwritten by accident, recoverable after a crash.

ASE trajectories (``.traj``) are ULM files: a header (item count, position of a
table of item offsets), then for every frame its arrays followed by a JSON block
(an int64 length, then the JSON text) that describes the frame and points at
its arrays; the offset table is rewritten or moved as frames are added. A file
cut short — a killed job, a full disk, a partial copy — can have a header and
table that point past its end, and ASE then fails with "buffer is smaller than
requested size". Every frame whose JSON block and arrays were written whole is
still in the file: :func:`recover_trajectory` finds them by their JSON blocks
and writes a valid file of them.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import numpy as np

__all__ = ["check_trajectory_target", "complete_frames", "recover_trajectory"]

_MAGIC = (b"- of Ulm", b"AFFormat")
_HEADER = 48  # magic 8, tag 16, version, nitems, position of the offset table
_N1 = 42      # ULM's offset-table block size (ase.io.ulm.N1)


def check_trajectory_target(trajectory, append):
    """Refuse to let an integrator truncate an existing trajectory.

    ``trajectory`` as given to an ASE dynamics: a file name (str or path), an
    open writer, or None. A name of an existing non-empty file is refused with
    FileExistsError unless ``append`` (ASE's ``append_trajectory=True``); when
    appending, a file that is not a complete trajectory (cut short by a crash)
    is a ValueError pointing to :func:`recover_trajectory` — ASE would append
    after the damaged frame and the file would stay unreadable.
    """
    if not isinstance(trajectory, (str, os.PathLike)):
        return
    path = Path(trajectory)
    if not path.is_file() or path.stat().st_size == 0:
        return
    if not append:
        raise FileExistsError(
            f"trajectory file {str(path)!r} exists and would be overwritten: pass "
            f"append_trajectory=True to continue it (a restart), remove it or choose "
            f"another name, or pass ase.io.Trajectory({str(path)!r}, 'w', atoms) to "
            f"overwrite it deliberately")
    problem = _damage(path)
    if problem:
        raise ValueError(
            f"cannot append to {str(path)!r}: {problem}. Recover its complete frames "
            f"with ase_spin.io.recover_trajectory({str(path)!r}) and continue from the "
            f"recovered file")


def _damage(path):
    """Why the file's header, offset table or last frame is not whole, or ''."""
    size = path.stat().st_size
    with open(path, "rb") as fd:
        head = fd.read(_HEADER)
        if len(head) < _HEADER or head[:8] not in _MAGIC:
            return "it is not an ASE trajectory (ULM) file, or its header is cut"
        nitems, pos0 = np.frombuffer(head[32:48], "<i8")
        if nitems < 0 or pos0 < _HEADER or pos0 + 8 * nitems > size:
            return "its table of frames points past the end of the file"
        if nitems == 0:
            return ""
        fd.seek(int(pos0))
        offsets = np.frombuffer(fd.read(8 * int(nitems)), "<i8")
        last = int(offsets[-1])
        if not _HEADER <= last <= size - 8:
            return "its last frame points past the end of the file"
        fd.seek(last)
        length = int(np.frombuffer(fd.read(8), "<i8")[0])
        if length < 2 or last + 8 + length > size:
            return "its last frame is cut short"
        data = _decode(fd.read(length))
        if data is None or not _arrays_before(data, last):
            return "its last frame is damaged"
    return ""


def _decode(raw):
    try:
        data = json.loads(raw)
    except (ValueError, UnicodeDecodeError):
        return None
    return data if isinstance(data, dict) else None


def _arrays_before(data, end):
    """Every array a frame's JSON refers to lies whole before ``end``."""
    for key, value in data.items():
        if isinstance(value, dict):
            if key.endswith(".") and "ndarray" in value:
                try:
                    shape, dtype, offset = value["ndarray"]
                    nbytes = int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize
                except (TypeError, ValueError):
                    return False
                if not (_HEADER <= offset and offset + nbytes <= end):
                    return False
            elif not _arrays_before(value, end):
                return False
    return True


def _frames(buf):
    """Positions of the JSON blocks of all frames written whole, in file order."""
    found = []
    size = len(buf)
    for match in re.finditer(rb"\{", buf):
        start = match.start()
        x = start - 8
        if x < _HEADER:
            continue
        length = int.from_bytes(buf[x:start], "little")
        end = start + length
        if length < 2 or end > size or buf[end - 1] != 0x7D:  # "}"
            continue
        data = _decode(buf[start:end])
        if data is not None and _arrays_before(data, x):
            found.append((x, end))
    # a frame's JSON may contain "{" itself: keep only blocks not inside another
    frames = []
    last_end = 0
    for x, end in found:
        if x >= last_end:
            frames.append((x, end))
            last_end = end
    return frames


def _read(path):
    buf = Path(path).read_bytes()
    if len(buf) < _HEADER or buf[:8] not in _MAGIC:
        raise ValueError(f"{str(path)!r} is not an ASE trajectory (ULM) file or its header "
                         "is cut: nothing to recover")
    return buf


def complete_frames(path):
    """Number of frames of a trajectory file that were written whole (whatever
    its header says)."""
    return len(_frames(_read(path)))


def recover_trajectory(path, output=None, overwrite=False):
    """Write the complete frames of a damaged or truncated trajectory to a new file.

    Parameters
    ----------
    path : str or path
        An ASE trajectory (``.traj``), possibly cut short mid-frame.
    output : str or path, optional
        Where to write them; default ``<name>.recovered.traj`` beside it.
    overwrite : bool
        Replace ``output`` if it exists (else FileExistsError).

    Returns
    -------
    int
        Number of frames recovered. They are byte for byte the frames of the
        original file (positions, momenta, spins, cell, constraints, stored
        calculator results), and the new file can be read, and appended to, by
        ASE as usual.

    Raises ValueError if the file has no complete frame.
    """
    path = Path(path)
    buf = _read(path)
    frames = _frames(buf)
    if not frames:
        raise ValueError(f"{str(path)!r} holds no complete frame to recover")
    output = Path(output) if output is not None else path.with_name(
        path.stem + ".recovered" + path.suffix)
    if output.resolve() == path.resolve():
        raise ValueError("output must be a new file, not the damaged one")
    if output.exists() and not overwrite:
        raise FileExistsError(f"{str(output)!r} exists; pass overwrite=True to replace it")
    n = len(frames)
    body = bytearray(buf[:frames[-1][1]])
    body += b"#" * (-len(body) % 8)
    pos0 = len(body)
    # a table as long as ASE's own for n items, so that appending writes the next
    # offset into the table's padding, not over the next frame
    capacity = 1
    while n > capacity:
        capacity *= _N1
    table = np.zeros(capacity, "<i8")
    table[:n] = [x for x, _ in frames]
    body += table.tobytes()
    body[32:48] = np.array([n, pos0], "<i8").tobytes()
    tmp = output.with_name(output.name + ".part")
    tmp.write_bytes(bytes(body))
    os.replace(tmp, output)
    return n
