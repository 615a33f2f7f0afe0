"""Watch a folder for new RAW files and hand one over only once it is complete.

A file is taken once its name is a RAW file's, its size and modification time held for two polls,
and, for a TIFF-based RAW, every image strip or tile lies within the file; ``incomplete`` says why
not. The rules: docs/explanations/camera.md.
"""
from __future__ import annotations

from pathlib import Path

TIFF_MAGIC = (b"II*\x00", b"MM\x00*")  # little- and big-endian TIFF headers


class HotFolder:
    """The new RAW files of ``folder`` (those not there when it was made): ``poll()`` returns the
    newest that is complete (module doc), else None. ``incomplete``: {path: why} of the files that
    stood unchanged over two polls but are not whole."""

    def __init__(self, folder, suffixes) -> None:
        self.folder = Path(folder)
        self.suffixes = tuple(s.lower() for s in suffixes)
        self._before = self.raw_files()
        self._last: dict[Path, tuple[int, int]] = {}  # path -> (size, mtime_ns) at the last poll
        self.incomplete: dict[Path, str] = {}

    def raw_files(self) -> set[Path]:
        """The folder's files with a RAW name (rule 1)."""
        return {p for p in self.folder.iterdir() if not p.name.startswith(".") and p.suffix.lower() in self.suffixes}

    def pending(self) -> list[Path]:
        """The new RAW files seen at the last poll, complete or not."""
        return sorted(self._last)

    def poll(self) -> Path | None:
        """Look once: the newest new file that is complete, else None."""
        now, complete = {}, []
        for path in self.raw_files() - self._before:
            try:
                st = path.stat()
            except FileNotFoundError:  # renamed or removed since the listing
                continue
            now[path] = (st.st_size, st.st_mtime_ns)
            if st.st_size and self._last.get(path) == now[path]:  # rule 2
                why = tiff_incomplete(path, st.st_size)
                if why is None:
                    complete.append((st.st_mtime_ns, path))
                    self.incomplete.pop(path, None)
                else:
                    self.incomplete[path] = why
        self._last = now
        return max(complete)[1] if complete else None


def tiff_incomplete(path: Path, size: int) -> str | None:
    """Why a TIFF-based file of ``size`` bytes is not whole yet (rule 3); None when it is, or when
    it is not TIFF-based."""
    import tifffile

    with open(path, "rb") as fh:
        if fh.read(4) not in TIFF_MAGIC:
            return None
    try:
        with tifffile.TiffFile(path) as tif:
            pages = list(tif.pages)
            if not pages:
                return "no image directory yet"
            end = 0
            while pages:
                page = pages.pop()
                end = max([end, *(o + n for o, n in zip(page.dataoffsets, page.databytecounts))])
                pages.extend(getattr(page, "pages", None) or ())  # SubIFDs: a DNG's raw image is often one
    except Exception as exc:  # noqa: BLE001 - any parse failure of a file being written means "not yet"
        return f"its TIFF structure does not parse yet ({type(exc).__name__}: {exc})"
    if end > size:
        return f"its image data ends at byte {end}, the file has {size}"
    return None
