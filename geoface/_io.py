"""Safe output: atomic files and folders with the user's umask, and one output-path policy.

* :func:`atomic_path` / :func:`atomic_dir` write to a temporary beside the target and rename
  it into place on success; on failure (an exception, SIGINT, SIGTERM) the temporary is
  removed and the target is untouched.  Results get the user's umask (0644 files, 0755
  folders under umask 022), not the temporary's 0600/0700.
* Temporaries are named ``.<target>.geoface-<pid>-<random>``; one left behind by a run that
  was killed (SIGKILL) is removed by the next run writing the same target.
* :func:`check_outputs` is the policy every command applies before doing any work: an
  output may not be an input, lie inside an input folder, contain an input, or collide with
  another output; an existing output is replaced only when the user says so (``--force``).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path

from .errors import GeofaceError

__all__ = ["atomic_path", "atomic_dir", "atomic_write_text", "check_outputs", "default_mode", "OutputError",
           "clean_stale_temporaries", "image_size", "occupied", "MAX_IMAGE_PIXELS", "replace_dir", "check_input",
           "check_tree", "copy_checked"]

#: the largest image geoface decodes (a 16384^2 geometry image); a header claiming more is refused
MAX_IMAGE_PIXELS = 16384 * 16384


def image_size(path: str | os.PathLike, *, max_pixels: int = MAX_IMAGE_PIXELS) -> tuple[int, int] | None:
    """``(width, height)`` from a PNG or JPEG header without decoding the image; raises
    :class:`GeofaceError` when the header claims more than ``max_pixels`` (decoding a forged
    60000² header would allocate tens of GB).  None for other formats or a short file."""
    import struct

    p = Path(path)
    with open(p, "rb") as fh:
        head = fh.read(64 * 1024)
    size = None
    if head[:8] == b"\x89PNG\r\n\x1a\n" and len(head) >= 24 and head[12:16] == b"IHDR":
        size = struct.unpack(">II", head[16:24])
    elif head[:2] == b"\xff\xd8":
        i = 2
        while i + 9 < len(head):
            if head[i] != 0xFF:
                i += 1
                continue
            marker = head[i + 1]
            if marker in (0xC0, 0xC1, 0xC2):
                h, w = struct.unpack(">HH", head[i + 5:i + 9])
                size = (w, h)
                break
            i += 2 + struct.unpack(">H", head[i + 2:i + 4])[0]
    if size is not None and size[0] * size[1] > max_pixels:
        raise GeofaceError(f"{p}: the image claims {size[0]}x{size[1]} pixels, more than geoface decodes "
                           f"({max_pixels} pixels)")
    return size

_TAG = "geoface"


class OutputError(GeofaceError):
    """An output path the policy refuses (an input, inside an input, taken, or existing)."""


def default_mode(folder: bool = False) -> int:
    """File (0o666) or folder (0o777) permissions under the process's umask."""
    mask = os.umask(0)
    os.umask(mask)
    return (0o777 if folder else 0o666) & ~mask


def occupied(path: Path) -> bool:
    """Whether ``path`` holds something a write would replace: a file, or a folder that is
    not empty (an empty folder may become an output)."""
    path = Path(path)
    if path.is_dir():
        return any(path.iterdir())
    return path.exists()


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def clean_stale_temporaries(target: str | os.PathLike) -> int:
    """Remove temporaries of ``target`` left by geoface runs that no longer exist; returns
    how many were removed."""
    target = Path(target)
    folder = target.parent if str(target.parent) else Path(".")
    if not folder.is_dir():
        return 0
    prefix = f".{target.name}.{_TAG}-"
    removed = 0
    for p in folder.glob(f"{prefix}*"):
        try:
            pid = int(p.name[len(prefix):].split("-", 1)[0])
        except ValueError:
            continue
        if _pid_alive(pid):
            continue
        with contextlib.suppress(OSError):
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p)
            else:
                p.unlink()
            removed += 1
    return removed


def clean_tree_temporaries(root: str | os.PathLike, depth: int = 2) -> int:
    """:func:`clean_stale_temporaries` for every temporary of a dead geoface run found in
    ``root`` and its folders down to ``depth`` levels (a dataset's item folders); returns how
    many were removed."""
    root = Path(root)
    removed = 0
    if not root.is_dir() or root.is_symlink():
        return 0
    for p in list(root.iterdir()):
        name = p.name
        if name.startswith(".") and f".{_TAG}-" in name:
            target = name[1: name.index(f".{_TAG}-")]
            removed += clean_stale_temporaries(root / target)
        elif depth > 1 and p.is_dir() and not p.is_symlink():
            removed += clean_tree_temporaries(p, depth - 1)
    return removed


def temp_prefix(target: Path) -> str:
    return f".{target.name}.{_TAG}-{os.getpid()}-"


@contextlib.contextmanager
def atomic_path(target: str | os.PathLike, suffix: str | None = None):
    """Yield a temporary path in the target's folder; rename it onto ``target`` on success.

    On any exception the temporary file is removed and ``target`` is untouched, so a
    failed write never leaves a partial or overwritten output.  The result gets the user's
    umask.
    """
    target = Path(target)
    folder = target.parent if str(target.parent) else Path(".")
    if not folder.exists():
        folder.mkdir(parents=True, exist_ok=True)
    clean_stale_temporaries(target)
    sfx = suffix if suffix is not None else "".join(target.suffixes[-1:])
    fd, tmp = tempfile.mkstemp(prefix=temp_prefix(target), suffix=f".tmp{sfx}", dir=folder)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.chmod(tmp_path, default_mode())
        os.replace(tmp_path, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise


@contextlib.contextmanager
def atomic_dir(target: str | os.PathLike, *, overwrite: bool = False):
    """Yield a temporary folder beside ``target``; on success it becomes ``target``.

    An existing ``target`` (see :func:`occupied`) is refused unless ``overwrite``; then it is
    moved aside and removed only after the new folder is in place.  On failure the temporary folder is
    removed and ``target`` is untouched.  Folders get the user's umask.
    """
    target = Path(target)
    parent = target.parent if str(target.parent) else Path(".")
    if occupied(target) and not overwrite:
        raise OutputError(f"{target} exists; pass --force to replace it")
    parent.mkdir(parents=True, exist_ok=True)
    clean_stale_temporaries(target)
    tmp = Path(tempfile.mkdtemp(prefix=temp_prefix(target), dir=parent))
    try:
        yield tmp
        chmod_tree(tmp)
        replace_dir(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def output_folder(out, force: bool):
    """A context giving the temporary folder to write an ``-o OUT_DIR`` into (renamed onto
    ``OUT_DIR`` when complete, so that a kill or a ``--force`` rerun never leaves a mix of runs;
    an occupied ``OUT_DIR`` needs ``force``), or None when ``out`` is None."""
    return contextlib.nullcontext(None) if out is None else atomic_dir(out, overwrite=force)


def chmod_tree(root: Path) -> None:
    dmode, fmode = default_mode(True), default_mode(False)
    os.chmod(root, dmode)
    for dirpath, dirnames, filenames in os.walk(root):
        for d in dirnames:
            os.chmod(os.path.join(dirpath, d), dmode)
        for f in filenames:
            p = os.path.join(dirpath, f)
            if not os.path.islink(p):
                os.chmod(p, fmode)


def replace_dir(tmp: Path, folder: Path) -> None:
    """Move the finished folder ``tmp`` onto ``folder``, replacing an old one."""
    old = None
    if folder.is_symlink():  # (only with --force: check_outputs refuses a link otherwise) replace the link itself
        folder.unlink()
    elif folder.exists():
        old = folder.with_name(f".{folder.name}.{_TAG}-{os.getpid()}-old")
        if old.exists():
            shutil.rmtree(old, ignore_errors=True)
        os.replace(folder, old)
    os.replace(tmp, folder)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def write_image(path: str | os.PathLike, image) -> None:
    """Encode ``image`` (OpenCV's BGR order, uint8 or uint16) by the file's extension and write
    it: encoding problems are a :class:`GeofaceError`, a write the disk refuses (full, read-only)
    an :class:`OSError` with its errno, which ``cv2.imwrite``'s bare False would hide."""
    import cv2
    import numpy as np

    path = Path(path)
    ok, buf = cv2.imencode(path.suffix or ".png", np.ascontiguousarray(image))
    if not ok:
        raise GeofaceError(f"could not encode {path.name} as {path.suffix or '.png'}")
    with open(path, "wb") as fh:
        fh.write(buf.tobytes())


def atomic_write_text(target: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8) to ``target`` through :func:`atomic_path`."""
    with atomic_path(target) as tmp:
        tmp.write_text(text, encoding="utf-8")


def _resolved(p) -> Path:
    try:
        return Path(os.path.abspath(os.path.expanduser(str(p)))).resolve()
    except (RuntimeError, OSError) as e:  # Python raises RuntimeError for a loop of links
        raise GeofaceError(f"{p}: a loop of symbolic links ({type(e).__name__})") from None


def check_tree(src, _seen: set | None = None) -> None:
    """:func:`check_input` for the file or folder ``src`` and everything it holds, links followed:
    a loop of links (a folder linking to itself or above), a device, a FIFO or a socket anywhere
    inside is a :class:`GeofaceError`, before any work."""
    src = Path(src)
    check_input(src)
    if src.is_dir():
        real = os.path.realpath(src)
        seen = set() if _seen is None else _seen
        if real in seen:
            raise GeofaceError(f"{src}: a link to a folder that holds it (a loop)")
        seen.add(real)
        for q in sorted(src.iterdir()):
            check_tree(q, seen)
        seen.discard(real)


def copy_checked(src, dst) -> None:
    """Copy the file or folder ``src`` to ``dst`` as what it holds (links to regular files and
    folders followed), after :func:`check_tree`: ``shutil`` alone would copy ``/dev/zero`` until
    the disk is full, or wait on a FIFO for ever."""
    check_tree(src)
    if Path(src).is_dir():
        shutil.copytree(src, dst)
    else:
        shutil.copy2(src, dst)


def check_input(p) -> None:
    """An input path the commands can read: a loop of symbolic links, a device, a FIFO or a socket
    (which would block, or never end: ``/dev/zero``) is refused with one line. A path that does
    not exist is left to the command (it names what it expected)."""
    import stat

    q = os.path.expanduser(str(p))
    try:
        st = os.stat(q)  # follows links: what the command would read
    except FileNotFoundError:
        return
    except OSError as e:
        import errno

        if e.errno == errno.ELOOP:
            raise GeofaceError(f"{p}: a loop of symbolic links") from None
        raise GeofaceError(f"{p}: cannot be read ({e.strerror})") from None
    kind = next((name for test, name in ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                                         (stat.S_ISFIFO, "a FIFO"), (stat.S_ISSOCK, "a socket")) if test(st.st_mode)), None)
    if kind:
        raise GeofaceError(f"{p} is {kind}, not a file or folder")


def _inside(child: Path, parent: Path) -> bool:
    try:
        child.relative_to(parent)
        return child != parent
    except ValueError:
        return False


def _check_kind(p: Path, force: bool) -> None:
    """An output is a regular file or folder (or nothing yet): a device, FIFO or socket is
    never replaced; a symbolic link is never written through, and is itself replaced only
    with ``force``."""
    import stat

    try:
        st = os.lstat(p)
    except (FileNotFoundError, NotADirectoryError):
        return
    except OSError as e:
        raise OutputError(f"{p}: cannot check the output ({e.strerror})") from None
    if stat.S_ISLNK(st.st_mode):
        if not force:
            raise OutputError(f"{p} is a symbolic link; geoface never writes through one (pass --force to replace "
                              "the link itself)")
        return
    if not (stat.S_ISREG(st.st_mode) or stat.S_ISDIR(st.st_mode)):
        raise OutputError(f"{p} is a device, FIFO or socket, not a file; choose a file name as the output")


def check_outputs(inputs=(), outputs=(), *, force: bool = False, resumable=()) -> None:
    """The output-path policy (module docs), applied before any work.

    Parameters
    ----------
    inputs : paths the command reads (files or folders); None entries are skipped
    outputs : paths it writes (files or folders, with their companion files)
    force : an existing output may be replaced
    resumable : outputs that may exist without ``force`` (a folder the command resumes)
    """
    for p in inputs:
        if p is not None:
            check_input(p)
    ins = [(p, _resolved(p)) for p in inputs if p is not None]
    outs = [(p, _resolved(p)) for p in outputs if p is not None]
    for p, _ in outs:
        _check_kind(Path(os.path.expanduser(str(p))), force)
    seen: dict = {}
    for p, rp in outs:
        if rp in seen:
            raise OutputError(f"two outputs are the same file: {seen[rp]} and {p}")
        seen[rp] = p
        for q, rq in ins:
            same = rp == rq
            if not same and rp.exists() and rq.exists():
                with contextlib.suppress(OSError):
                    same = os.path.samefile(rp, rq)
            if same:
                raise OutputError(f"refusing to overwrite the input {q}; choose another output")
            if rq.is_dir() and _inside(rp, rq):
                raise OutputError(f"the output {p} lies inside the input folder {q}; choose another place")
            if _inside(rq, rp):
                raise OutputError(f"the output {p} contains the input {q}; choose another place")
    res = {_resolved(p) for p in resumable if p is not None}
    for p, rp in outs:
        if occupied(rp) and not force and rp not in res:
            raise OutputError(f"{p} exists; pass --force to replace it")
