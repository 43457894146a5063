"""Reading and writing the files of long runs safely.

* Results written one JSON line per finished item (:func:`read_jsonl`), so long runs resume
  after a kill: a torn last line is what a kill leaves and is dropped; anything else that is
  not a record is corruption and an error naming the file and line.
* Corrupt inputs give one clear error: :func:`file_errors` turns whatever a parser raises on a
  truncated, empty or garbage file (``zipfile.BadZipFile``, ``json.JSONDecodeError``,
  ``tomllib.TOMLDecodeError``, ``KeyError``, ``UnicodeDecodeError``, ...) into a
  :class:`CorruptFileError` (a ``ValueError``) naming the file; :func:`read_json` and
  :func:`load_npz` are built on it.
* Nothing is left half written: :func:`atomic_write` writes a temporary file beside the target
  and renames it over the target only when the writing finished.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import platform
import uuid
import zipfile
import zlib
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from ._threads import blas_libraries

__all__ = [
    "CorruptFileError",
    "check_magic",
    "file_errors",
    "read_json",
    "load_npz",
    "read_jsonl",
    "atomic_write",
    "write_text_atomic",
    "write_json_atomic",
    "machine_record",
]

log = logging.getLogger(__name__)

#: What parsers raise on truncated, empty, garbage or wrong-shape content.
PARSE_ERRORS: tuple[type[BaseException], ...] = (
    ValueError, KeyError, IndexError, TypeError, AttributeError, EOFError, OSError,
    zipfile.BadZipFile, zlib.error,
)


class CorruptFileError(ValueError):
    """A file exists but cannot be used; the message names the file and what is wrong."""


def _one_line(exc: BaseException, path=None) -> str:
    """A parser's error as one line, without repeating ``path``."""
    if isinstance(exc, KeyError):
        return f"missing item {exc.args[0]!r}" if exc.args else "missing item"
    if isinstance(exc, UnicodeDecodeError):
        return f"not a text file (byte {exc.start}: {exc.reason})"
    if isinstance(exc, json.JSONDecodeError):
        return f"not valid JSON: {exc.msg}, line {exc.lineno} column {exc.colno}"
    text = " ".join(str(exc).split())
    if path is not None:
        text = text.replace(f"'{path}'", "").replace(str(path), "").strip(" :")
    kind = type(exc)
    if kind.__name__ == "TOMLDecodeError":
        return f"not valid TOML ({text})"
    if kind.__module__.split(".")[0] == "yaml":
        return f"not valid YAML ({text[:200]})"
    if isinstance(exc, (zipfile.BadZipFile, EOFError, zlib.error)):
        return f"truncated or not a valid archive ({text or kind.__name__})"
    return text or kind.__name__


@contextlib.contextmanager
def file_errors(path, what: str = "file", extra: tuple[type[BaseException], ...] = ()):
    """Re-raise a parser's error on ``path`` as one :class:`CorruptFileError` naming the file.

    ``FileNotFoundError`` and :class:`CorruptFileError` pass unchanged (they already name
    their file), as does the text of a ``ValueError`` naming ``path``; every other error of
    :data:`PARSE_ERRORS` (plus ``extra``, e.g. ``yaml.YAMLError``) becomes
    ``CorruptFileError("<what> <path>: <reason>")`` on one line.

    Parameters
    ----------
    path : str or Path
        The file being read, for the message.
    what : str
        What the file is ("model file", "config file", ...).
    extra : tuple of exception types
        More errors that mean bad content.
    """
    try:
        yield
    except (FileNotFoundError, CorruptFileError):
        raise
    except PARSE_ERRORS + tuple(extra) as exc:
        text = " ".join(str(exc).split())
        if isinstance(exc, ValueError) and str(path) in text:  # already names the file
            raise CorruptFileError(text) from exc
        raise CorruptFileError(f"{what} {path}: {_one_line(exc, path)}") from exc


def read_json(path, what: str = "JSON file", expect: type = dict):
    """The content of a JSON file, checked to be an ``expect`` (an object by default).

    Raises
    ------
    FileNotFoundError
        If it does not exist (message naming it).
    CorruptFileError
        Empty, truncated or not JSON, or not an ``expect``.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what} not found: {path}")
    with file_errors(path, what):
        text = path.read_bytes().decode("utf-8")
        if not text.strip():
            raise CorruptFileError(f"{what} {path}: empty file")
        data = json.loads(text)
    if expect is not None and not isinstance(data, expect):
        raise CorruptFileError(f"{what} {path}: expected a JSON "
                               f"{'object' if expect is dict else expect.__name__}, "
                               f"got {type(data).__name__}")
    return data


def load_npz(path, keys: Iterable[str] = (), what: str = "npz file") -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` archive (never unpickling), checked to hold ``keys``.

    Returns
    -------
    dict
        Name -> ndarray, read in full (the archive is closed).

    Raises
    ------
    FileNotFoundError
        If it does not exist.
    CorruptFileError
        Empty, truncated, garbage (not starting as a zip archive: a single ``.npy`` array,
        pickled data, ...), a pickled member, or missing one of ``keys``.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what} not found: {path}")
    with file_errors(path, what):
        # our own handle: numpy leaks the one it opens when the archive is unreadable
        with open(path, "rb") as fh:
            check_magic(fh, path, what, (b"PK\x03\x04", b"PK\x05\x06"), "an .npz archive")
            with np.load(fh, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
    missing = [k for k in keys if k not in arrays]
    if missing:
        raise CorruptFileError(f"{what} {path}: missing array(s) {missing}; "
                               f"found {sorted(arrays)}")
    return arrays


def check_magic(fh, path, what: str, magics: tuple[bytes, ...], kind: str) -> None:
    """Refuse an empty file or one that does not start like ``kind`` (rewinds ``fh``)."""
    head = fh.read(8)
    fh.seek(0)
    if not head:
        raise CorruptFileError(f"{what} {path}: empty file")
    if not any(head.startswith(m) for m in magics):
        raise CorruptFileError(f"{what} {path}: not {kind} (it starts with {head[:6]!r})")


def _torn(raw: bytes) -> bool:
    """Whether a last line looks cut by a kill: the start of a JSON object, or NUL padding."""
    s = raw.replace(b"\0", b"").strip()
    return not s or s.startswith(b"{")


def read_jsonl(path, required: Iterable[str] = (), repair: bool = False) -> list[dict]:
    """The JSON objects of a JSON-lines results file, in file order.

    Blank lines are ignored and a missing file reads as no records. A **torn last line** (the
    beginning of a JSON object, or NUL bytes, without a complete record: what a kill during a
    write leaves) is dropped with a warning naming the file and line; with ``repair`` the file
    is rewritten without it (and a last record missing its newline gets one), so records
    appended next start on a line of their own. Any other line that is not a JSON object, or
    lacks one of ``required``, is corruption: an error naming the file and line.

    Parameters
    ----------
    path : str or Path
    required : iterable of str
        Keys every record must have.
    repair : bool
        Rewrite the file (atomically) when its end needs fixing; resumable writers pass True.

    Returns
    -------
    list of dict

    Raises
    ------
    CorruptFileError
        A line other than a torn last one is not a complete record.
    """
    path = Path(path)
    if not path.exists():
        return []
    if not path.is_file():
        raise CorruptFileError(f"results file {path}: not a file")
    data = path.read_bytes()
    required = tuple(required)
    chunks = data.split(b"\n")  # the last chunk is b"" when the file ends with a newline
    last = max((i for i, c in enumerate(chunks) if c.strip()), default=-1)
    out = []
    keep = len(data)  # bytes kept when repairing
    for i, raw in enumerate(chunks):
        if not raw.strip():
            continue
        number = i + 1
        try:
            rec = json.loads(raw.decode("utf-8"))
            problem = None if isinstance(rec, dict) else f"a JSON {type(rec).__name__}"
        except json.JSONDecodeError as exc:
            rec, problem = None, f"{exc.msg}, column {exc.colno}"
        except UnicodeDecodeError as exc:
            rec, problem = None, _one_line(exc)
        if problem is not None and i == last and _torn(raw):
            log.warning("%s:%d: dropping an incomplete last line (an interrupted run?)",
                        path, number)
            keep = sum(len(c) + 1 for c in chunks[:i])
            break
        if problem is not None:
            raise CorruptFileError(f"results file {path}:{number}: not a JSON record "
                                   f"({problem}); fix or delete that line")
        missing = [k for k in required if k not in rec]
        if missing:
            raise CorruptFileError(f"results file {path}:{number}: record lacks {missing}")
        out.append(rec)
    if repair:
        fixed = data[:keep]
        if fixed and not fixed.endswith(b"\n"):
            fixed += b"\n"
        if fixed != data:
            with atomic_write(path, "wb") as fh:
                fh.write(fixed)
    return out


@contextlib.contextmanager
def atomic_write(path, mode: str = "w") -> Iterator:
    """An open temporary file that replaces ``path`` when the block finishes without error.

    The temporary file lives beside ``path`` (same file system, so the rename is atomic) and is
    removed if the block raises: a kill or an error never leaves ``path`` half written (it holds
    the old content or the new one). Parent folders are created.

    Parameters
    ----------
    path : str or Path
    mode : {"w", "wb"}
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"mode must be 'w' or 'wb', got {mode!r}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp")
    try:
        with open(tmp, mode.replace("w", "x")) as fh:
            yield fh
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def write_text_atomic(path, text: str) -> Path:
    """Write ``text`` to ``path`` through :func:`atomic_write`; returns the path."""
    with atomic_write(path) as fh:
        fh.write(text)
    return Path(path)


def write_json_atomic(path, obj, indent: int | None = 2, **kwargs) -> Path:
    """Write ``obj`` as JSON (newline-terminated) through :func:`atomic_write`."""
    return write_text_atomic(path, json.dumps(obj, indent=indent, **kwargs) + "\n")


def machine_record() -> dict:
    """What a record says of the machine that made it: ``platform``, ``processor``, ``python``
    and ``blas`` (:func:`dlsr._threads.blas_libraries`: each BLAS library's version and
    OpenBLAS's kernel set, which sets the last bits of every product)."""
    return {"platform": platform.platform(), "processor": platform.processor(),
            "python": platform.python_version(), "blas": blas_libraries()}
