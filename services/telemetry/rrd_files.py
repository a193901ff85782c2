"""Finding and opening a run's ``.rrd`` files: segments, single files, cut-off files.

A run recorded by the telemetry service is a sequence of segments ``<stem>.0000.rrd``,
``<stem>.0001.rrd``, ... in its run folder (``services.telemetry.recording``); a run recorded
in one file is one ``<stem>.rrd``. ``find_segments`` turns what a user names (a file,
a run folder, or the ``<stem>.rrd`` of a segmented run, which the launcher prints) into the
files of one recording, in order. ``read_store`` reads one file by streaming (a file
without footer, left by a SIGKILL, is read up to its last complete message).

Framing of an ``.rrd`` of rerun-sdk 0.41 (pinned; checked by the tests on files it wrote):
a 12-byte stream header (``RRF2``, version, options), then messages of a 16-byte header
(``kind``: u64 little-endian, ``length``: u64 LE) followed by ``length`` bytes of payload;
kind 0 ends the stream (the footer follows). A file cut inside a message (a crash while
writing) makes the SDK's reader fail as a whole; ``readable_length`` finds where the last
complete message ends, and ``read_store`` reads a copy cut there.
"""

from __future__ import annotations

import re
import shutil
import struct
import tempfile
import warnings
from pathlib import Path
from typing import Any

#: ``<stem>.<index>.rrd``: a segment (index of at least 4 digits).
SEGMENT_RE = re.compile(r"^(?P<stem>.+)\.(?P<index>\d{4,})\.rrd$")
#: Bytes of the stream header and of each message header of an ``.rrd``.
STREAM_HEADER_BYTES = 12
MESSAGE_HEADER_BYTES = 16
#: The stream header's magic bytes.
MAGIC = b"RRF2"
#: Stem preferred in a run folder holding several recordings.
PREFERRED_STEM = "telemetry"


def recording_stem(path: Path) -> tuple[str, int | None]:
    """(stem, segment index) of an ``.rrd`` file name; index None for a single file."""
    m = SEGMENT_RE.match(path.name)
    if m:
        return m["stem"], int(m["index"])
    return path.name.removesuffix(".rrd"), None


def _segments_of(folder: Path, stem: str) -> list[Path]:
    found = []
    for f in folder.glob(f"{glob_escape(stem)}.*.rrd"):
        s, i = recording_stem(f)
        if s == stem and i is not None and f.is_file():
            found.append((i, f))
    return [f for _i, f in sorted(found)]


def glob_escape(text: str) -> str:
    """`text` with the glob wildcards ``*?[`` escaped."""
    return re.sub(r"([*?\[])", r"[\1]", text)


def find_segments(path: str | Path) -> list[Path]:
    """The files of the recording `path` names, in order.

    * a segment file ``<stem>.<n>.rrd``: every segment of that stem in its folder;
    * another existing file: that file alone (a single-file recording);
    * ``<folder>/<stem>.rrd`` that does not exist, with segments of `stem` beside it;
    * a run folder: its ``telemetry`` recording (segments, else ``telemetry.rrd``), else
      the recording with the newest file.

    Raises:
        FileNotFoundError: nothing of that name, or a folder without a recording.
    """
    p = Path(path)
    if p.is_file():
        stem, index = recording_stem(p)
        return _segments_of(p.parent, stem) if index is not None else [p]
    if p.is_dir():
        groups: dict[str, list[Path]] = {}
        for f in p.glob("*.rrd"):
            if f.is_file():
                groups.setdefault(recording_stem(f)[0], []).append(f)
        if not groups:
            raise FileNotFoundError(f"{p}: no .rrd recording in this folder")
        if PREFERRED_STEM in groups:
            stem = PREFERRED_STEM
        else:
            stem = max(groups, key=lambda s: max(f.stat().st_mtime for f in groups[s]))
        segments = _segments_of(p, stem)
        return segments or [p / f"{stem}.rrd"]
    if p.suffix == ".rrd" and p.parent.is_dir():
        segments = _segments_of(p.parent, p.name.removesuffix(".rrd"))
        if segments:
            return segments
    raise FileNotFoundError(f"{p}: no such file or folder")


def readable_length(path: str | Path) -> tuple[int, bool]:
    """(bytes up to the end of the last complete message, whether the file ends there).

    A file whose message headers do not walk (not an ``.rrd`` of this framing) gives
    (its size, True): the SDK's reader then says what is wrong.
    """
    size = Path(path).stat().st_size
    with open(path, "rb") as f:
        if f.read(4) != MAGIC:
            return size, True
        off = STREAM_HEADER_BYTES
        f.seek(off)
        while off + MESSAGE_HEADER_BYTES <= size:
            kind, length = struct.unpack("<QQ", f.read(MESSAGE_HEADER_BYTES))
            end = off + MESSAGE_HEADER_BYTES + length
            if kind == 0:  # end of stream: the footer follows
                # whole unless the cut fell inside the footer: then every message is there,
                # read without the footer (as a killed writer's file)
                return (size, True) if end <= size else (off, False)
            if end > size:
                return off, False
            off = end
            f.seek(off)
        return off, off == size


def read_store(path: str | Path) -> tuple[Any, bool]:
    """(chunk store, complete) of one ``.rrd`` file, read by streaming.

    `complete` is False when the file has no footer (its writer was killed); a file cut
    inside a message is read up to the last complete one (from a cut copy).

    Raises:
        RuntimeError / ValueError: the SDK cannot read the file even when cut.
    """
    import rerun as rr  # here: finding files needs no Rerun (tools import this module)

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            store = rr.chunk.RrdReader(str(path)).stream().collect()
        except RuntimeError:
            length, whole = readable_length(path)
            if whole:
                raise
            with tempfile.TemporaryDirectory(prefix="rrd-cut-") as tmp:
                cut = Path(tmp) / Path(path).name
                with open(path, "rb") as src, open(cut, "wb") as dst:
                    shutil.copyfileobj(_Limited(src, length), dst)
                store = rr.chunk.RrdReader(str(cut)).stream().collect()
            return store, False
    complete = not any("no footer" in str(w.message) for w in caught)
    return store, complete


class _Limited:
    """The first `n` bytes of a binary file (for ``shutil.copyfileobj``)."""

    def __init__(self, f: Any, n: int) -> None:
        self._f, self._left = f, n

    def read(self, size: int = -1) -> bytes:
        if self._left <= 0:
            return b""
        size = self._left if size < 0 else min(size, self._left)
        data = self._f.read(size)
        self._left -= len(data)
        return data
