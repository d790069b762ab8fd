"""The one file writer of the package (no JAX here).

Every file jaxhyst writes — CSV, JSON, Markdown, PNG, checkpoints, saved models — goes
through `write_bytes` / `write_text`, which pick one of two ways by what the path names:

- **A regular file, or nothing yet**: written atomically — a temporary file in the
  directory of the final target, flushed and fsynced, then renamed over it — so that an
  interrupted write never leaves a half-written file. An existing file keeps its
  permission bits (a new one gets the umask's). A symbolic link stays a link: its target
  is what is replaced.
- **Anything else** — a character or block device (``/dev/null``, a tape), a FIFO, a
  socket, or a path that passes through ``/dev`` or ``/proc`` (``/dev/stdout``,
  ``/dev/fd/3``, ``/proc/self/fd/1``): written in place, as ``cat > path`` would. A
  rename would *replace* the device node or the link with a regular file.

A directory is refused with `IsADirectoryError`.
"""

from __future__ import annotations

import os
import stat
import tempfile
import threading

#: Held while the umask is read (setting it is the only way to read it): the kept traces
#: are written from a background thread too (`jaxhyst._kept_files`).
_UMASK_READ = threading.Lock()
#: Link targets under these directories are special files (descriptors, terminals,
#: devices) whatever ``stat`` says of what lies behind them.
_SPECIAL_ROOTS = ("/dev/", "/proc/")


def _through_special_link(path: str) -> bool:
    """Whether ``path`` is a symbolic link (or a chain of them) that passes through
    ``/dev`` or ``/proc``: ``/dev/stdout`` → ``/proc/self/fd/1`` → the shell's file."""
    seen = 0
    while os.path.islink(path) and seen < 40:
        target = os.readlink(path)
        path = os.path.normpath(os.path.join(os.path.dirname(path), target))
        if path.startswith(_SPECIAL_ROOTS):
            return True
        seen += 1
    return False


def writes_in_place(path: str | os.PathLike) -> bool:
    """Whether `write_bytes` writes ``path`` in place (a device, FIFO, socket or a link
    through ``/dev`` / ``/proc``) rather than by an atomic rename."""
    path = os.fspath(path)
    try:
        mode = os.stat(path).st_mode  # (follows links)
    except OSError:  # nothing there (or a parent is not a directory): a new regular file
        return False
    if stat.S_ISDIR(mode):
        return False
    absolute = os.path.abspath(path)
    return (not stat.S_ISREG(mode) or absolute.startswith(_SPECIAL_ROOTS)
            or _through_special_link(absolute))


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` (see the module docstring for how). Missing parent
    directories of a new regular file are created."""
    path = os.fspath(path)
    if os.path.isdir(path):
        raise IsADirectoryError(f"{path} is a directory; give a file name.")
    if writes_in_place(path):
        with open(path, "wb") as fh:
            fh.write(data)
        return
    target = os.path.realpath(path)  # a symbolic link: replace its target, keep the link
    try:
        mode = stat.S_IMODE(os.stat(target).st_mode)
    except (FileNotFoundError, NotADirectoryError):  # (a new file: said below if it cannot be)
        with _UMASK_READ:  # (read by setting it: one writer thread at a time, or
            umask = os.umask(0)  # two would leave the process's umask at 0)
            os.umask(umask)
        mode = 0o666 & ~umask
    directory = os.path.dirname(target)
    try:
        os.makedirs(directory, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{os.path.basename(target)}.", suffix=".tmp",
                                   dir=directory)
    except OSError as err:  # (the file asked for, not the temporary one, in one line)
        raise OSError(err.errno, f"cannot write {path} ({err.strerror}); choose a "
                                 "writable folder") from None
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, mode)  # mkstemp makes 0600
        os.replace(tmp, target)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_text(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` as `write_bytes` does."""
    if not isinstance(text, str):
        raise TypeError(f"write_text needs a str; got {type(text).__name__}.")
    write_bytes(path, text.encode("utf-8"))
