"""Pointing files: measurement dump files and named saved models (OpenTCI §14.2).

How it works
------------
*Dump files* (POINTINGPARAMS.DUMPFILE / LOADFILE) are text: a header of ``# key: value``
lines naming the format, the mount, the site, the time base and the refraction in use, then
one line per :class:`~tcs.pointing.model.Sample` with nine numbers separated by blanks::

    utc ra_h dec_deg ideal1 ideal2 axis1 axis2 offset1 offset2

(degrees for the axes; Unix seconds; floats written with ``repr`` so they read back exactly).
A sample is appended with flush + fsync, so after a crash the file holds every sample taken
before it; a torn last line (no newline, unparsable) is ignored on load, any other bad line
is an error naming file and line.

*Saved models* (POINTINGPARAMS.LIST / LOAD / SAVE / ERASE) are files ``<name>.model`` in one
directory, text ``key value`` lines ending with the line ``end``; a fit report may follow the
header as ``#`` comment lines. SAVE writes a temporary file ``.<name>.<random>.tmp`` in the same
directory, fsyncs it, renames it over the target (atomic on POSIX) and fsyncs the directory:
a kill at any moment leaves either the old model or the new one, never a mixture. LIST
ignores temporary files, and every start removes those of saves that never finished (older
than a minute); a file without its ``end`` line is reported as damaged.

Model names: 1–64 characters of letters, digits, ``_ - + .``, not starting with ``.``.

What may touch it
-----------------
Blocking file I/O: call from a worker thread (``asyncio.to_thread``), never from the control
loop. One :class:`ModelStore` per directory; concurrent SAVEs of the same name are safe (the
last rename wins).
"""

from __future__ import annotations

import logging
import math
import os
import re
import stat
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from tcs.errors import RequestRefused, TcsError
from tcs.pointing.astrometry import Refraction, Site, TimeBase
from tcs.pointing.model import MOUNT_TERMS, PointingModel, Sample

__all__ = ["DumpHeader", "write_dump_header", "append_sample", "load_dump", "ModelStore",
           "atomic_write_text", "DUMP_FORMAT", "MODEL_FORMAT"]

DUMP_FORMAT = "tcs-pointing-dump 1"
MODEL_FORMAT = "tcs-pointing-model 1"
_SAMPLE_FIELDS = ("utc", "ra", "dec", "ideal1", "ideal2", "axis1", "axis2", "offset1", "offset2")
_NAME = re.compile(r"[A-Za-z0-9_+\-][A-Za-z0-9_+.\-]{0,63}")
_SUFFIX = ".model"
_SUFFIX_TMP = ".tmp"
#: s after which a temporary file of a save is an orphan (a save takes milliseconds).
ORPHAN_AGE = 60.0

log = logging.getLogger(__name__)


def atomic_write_text(path: str | os.PathLike, text: str, *, keep_mode: bool = False) -> None:
    """Replace ``path`` with ``text`` atomically (temp file, fsync, rename, fsync dir).

    ``keep_mode``: the new file gets the old one's permission bits, and its owner and group
    when the process may set them (root) — for files other users read (``/etc/tcs``).
    """
    path = Path(path)
    directory = path.parent
    old = path.stat() if keep_mode else None
    fd, tmp = tempfile.mkstemp(dir=directory, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            if old is not None:
                os.fchmod(f.fileno(), stat.S_IMODE(old.st_mode))
                if (old.st_uid, old.st_gid) != (os.geteuid(), os.getegid()):
                    try:
                        os.fchown(f.fileno(), old.st_uid, old.st_gid)
                    except PermissionError:
                        pass  # not root: the file becomes ours, the mode is kept
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    dfd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(dfd)
    finally:
        os.close(dfd)


# -- dump files ---------------------------------------------------------------------------

@dataclass(frozen=True)
class DumpHeader:
    """What a dump file records about the conditions of its samples."""

    mount: str
    site: Site
    timebase: TimeBase
    refraction: Refraction

    def text(self) -> str:
        s, t, r = self.site, self.timebase, self.refraction
        return (f"# format: {DUMP_FORMAT}\n"
                f"# mount: {self.mount}\n"
                f"# site: latitude={s.latitude!r} longitude={s.longitude!r} height={s.height!r}\n"
                f"# timebase: tai_utc={t.tai_utc!r} ut1_utc={t.ut1_utc!r}\n"
                f"# refraction: mode={r.mode} temperature={r.temperature!r} "
                f"pressure={r.pressure!r}\n"
                f"# columns: {' '.join(_SAMPLE_FIELDS)}\n")


def _kv(text: str) -> dict[str, str]:
    out = {}
    for part in text.split():
        key, sep, value = part.partition("=")
        if not sep:
            raise ValueError(f"expected key=value, got {part!r}")
        out[key] = value
    return out


def write_dump_header(path: str | os.PathLike, header: DumpHeader) -> None:
    """Start a new dump file at ``path`` (replacing any old one) with ``header``."""
    atomic_write_text(path, header.text())


def append_sample(path: str | os.PathLike, sample: Sample) -> None:
    """Append one sample line to a dump file and make it durable (flush + fsync)."""
    line = " ".join(repr(float(getattr(sample, f))) for f in _SAMPLE_FIELDS) + "\n"
    with open(path, "a", encoding="utf-8") as f:
        f.write(line)
        f.flush()
        os.fsync(f.fileno())


def load_dump(path: str | os.PathLike) -> tuple[DumpHeader, list[Sample]]:
    """Read a dump file: its header and samples.

    Raises
    ------
    TcsError
        The file cannot be read, the header is missing or wrong, or a line (other than a
        torn last line) is not nine numbers; the message names file and line.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise TcsError(f"pointing dump {path}: cannot read: {e.strerror or e}") from None
    except UnicodeDecodeError:
        raise TcsError(f"pointing dump {path}: not a text file") from None
    lines = text.split("\n")
    torn = lines[-1] != ""      # last line without newline: maybe a write cut short
    if not torn:
        lines = lines[:-1]
    head: dict[str, str] = {}
    samples: list[Sample] = []
    for number, line in enumerate(lines, 1):
        where = f"pointing dump {path}, line {number}"
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            key, sep, value = stripped[1:].partition(":")
            if sep:
                head[key.strip()] = value.strip()
            continue
        parts = stripped.split()
        try:
            values = [float(p) for p in parts]
            if len(values) != len(_SAMPLE_FIELDS) or not all(map(math.isfinite, values)):
                raise ValueError
        except ValueError:
            if torn and number == len(lines):
                break
            raise TcsError(f"{where}: expected {len(_SAMPLE_FIELDS)} numbers "
                           f"({' '.join(_SAMPLE_FIELDS)})") from None
        samples.append(Sample(*values))
    try:
        if head.get("format") != DUMP_FORMAT:
            raise ValueError(f"format is {head.get('format')!r}, expected {DUMP_FORMAT!r}")
        mount = head["mount"]
        if mount not in MOUNT_TERMS:
            raise ValueError(f"mount {mount!r} is not one of {list(MOUNT_TERMS)}")
        s, t, r = _kv(head["site"]), _kv(head["timebase"]), _kv(head["refraction"])
        header = DumpHeader(
            mount=mount,
            site=Site(float(s["latitude"]), float(s["longitude"]), float(s["height"])),
            timebase=TimeBase(float(t["tai_utc"]), float(t["ut1_utc"])),
            refraction=Refraction(int(r["mode"]), float(r["temperature"]), float(r["pressure"])),
        )
    except KeyError as e:
        raise TcsError(f"pointing dump {path}: header lacks {e.args[0]!r}") from None
    except (ValueError, TcsError) as e:
        raise TcsError(f"pointing dump {path}: bad header: {e}") from None
    return header, samples


# -- saved models -------------------------------------------------------------------------

def _check_name(name: str) -> str:
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        raise RequestRefused(f"pointing model name {name!r}: use 1-64 letters, digits, '_', "
                             "'-', '+', '.', not starting with '.'", keyword="RANGE")
    return name


class ModelStore:
    """Named pointing models saved as files in one directory (created on first save).

    Parameters
    ----------
    directory : where ``<name>.model`` files live.
    """

    def __init__(self, directory: str | os.PathLike):
        self.directory = Path(directory)
        self.sweep_orphans()

    def sweep_orphans(self, min_age: float = ORPHAN_AGE) -> list[str]:
        """Remove temporary files of saves that never finished (a kill mid-SAVE) and are older
        than ``min_age`` s (a save in progress elsewhere takes milliseconds); returns their
        names. Run at every start, so they do not pile up across restarts."""
        removed = []
        try:
            entries = os.listdir(self.directory)
        except OSError:
            return removed
        now = time.time()
        for entry in entries:
            if not (entry.startswith(".") and entry.endswith(_SUFFIX_TMP) and _SUFFIX in entry):
                continue
            path = self.directory / entry
            try:
                if now - path.stat().st_mtime >= min_age:
                    path.unlink()
                    removed.append(entry)
            except OSError:
                continue
        if removed:
            log.info("pointing models: removed %d unfinished save(s) in %s: %s", len(removed),
                     self.directory, ", ".join(removed))
        return removed

    def path(self, name: str) -> Path:
        """File of a model name (validated)."""
        return self.directory / (_check_name(name) + _SUFFIX)

    def list(self) -> list[str]:
        """Names of the saved models, sorted (temporary files of unfinished saves excluded)."""
        try:
            entries = os.listdir(self.directory)
        except FileNotFoundError:
            return []
        names = [e[:-len(_SUFFIX)] for e in entries
                 if e.endswith(_SUFFIX) and _NAME.fullmatch(e[:-len(_SUFFIX)])]
        return sorted(names)

    def save(self, name: str, model: PointingModel, *, errors: dict[str, float] | None = None,
             report: str = "") -> None:
        """Save ``model`` under ``name`` atomically (replacing a model of that name).

        ``errors`` (term → 1σ, degrees) and ``report`` (free text, stored as comments)
        are kept for the operator.
        """
        path = self.path(name)
        lines = [f"format {MODEL_FORMAT}", f"mount {model.mount}",
                 f"latitude {model.latitude!r}"]
        for line in report.splitlines():
            lines.append(f"# {line}")
        for term in model.terms:
            if term in model.coefficients:
                sigma = (errors or {}).get(term)
                extra = f" {sigma!r}" if sigma is not None else ""
                lines.append(f"term {term} {model.coefficients[term]!r}{extra}")
        lines.append("end")
        self.directory.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, "\n".join(lines) + "\n")

    def load(self, name: str) -> PointingModel:
        """The model saved under ``name``.

        Raises
        ------
        RequestRefused : no model of that name (or a bad name).
        TcsError : the file is damaged (names file and line).
        """
        path = self.path(name)
        try:
            text = path.read_text(encoding="utf-8")
        except FileNotFoundError:
            raise RequestRefused(f"no saved pointing model named {name!r}", keyword="RANGE") from None
        except OSError as e:
            raise TcsError(f"pointing model {path}: cannot read: {e.strerror or e}") from None
        except UnicodeDecodeError:
            raise TcsError(f"pointing model {path}: not a text file") from None
        return _parse_model(path, text)

    def erase(self, name: str) -> None:
        """Delete the model saved under ``name``; RequestRefused if there is none."""
        path = self.path(name)
        try:
            path.unlink()
        except FileNotFoundError:
            raise RequestRefused(f"no saved pointing model named {name!r}", keyword="RANGE") from None


def _parse_model(path: Path, text: str) -> PointingModel:
    mount = None
    latitude = 0.0
    coefficients: dict[str, float] = {}
    ended = False
    fmt = None
    for number, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        where = f"pointing model {path}, line {number}"
        if ended:
            raise TcsError(f"{where}: text after 'end'")
        key, _, rest = line.partition(" ")
        rest = rest.strip()
        try:
            if key == "format":
                fmt = rest
            elif key == "mount":
                mount = rest
            elif key == "latitude":
                latitude = float(rest)
            elif key == "term":
                parts = rest.split()
                if len(parts) not in (2, 3):
                    raise ValueError("expected 'term NAME VALUE [SIGMA]'")
                coefficients[parts[0]] = float(parts[1])
            elif key == "end":
                ended = True
            else:
                raise ValueError(f"unknown key {key!r}")
        except ValueError as e:
            raise TcsError(f"{where}: {e}") from None
    if fmt != MODEL_FORMAT:
        raise TcsError(f"pointing model {path}: format {fmt!r}, expected {MODEL_FORMAT!r}")
    if not ended:
        raise TcsError(f"pointing model {path}: damaged (no 'end' line)")
    if mount not in MOUNT_TERMS:
        raise TcsError(f"pointing model {path}: mount {mount!r} is not one of {list(MOUNT_TERMS)}")
    try:
        return PointingModel(mount, coefficients, latitude)
    except TcsError as e:
        raise TcsError(f"pointing model {path}: {e.message}") from None
