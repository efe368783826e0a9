"""A run's results folder: one run writes into it at a time (a lock), an earlier run's results
are never taken for this one's (refused, or cleared first when the user says so), and each
result file appears whole (written aside, then moved into place)."""

from __future__ import annotations

import fcntl
import os
import shutil
from contextlib import contextmanager
from pathlib import Path

LOCK = ".yowo.lock"
STAGING = ".yowo.partial"
# What marks a folder as holding a YOWO run's results.
RUN_MARKERS = ("run_log.yaml", "params.yaml", "cameras.yaml", "logs")


class OutputFolderError(ValueError):
    """The results folder cannot be used; the message names it and the option to pass."""


@contextmanager
def claimed_output(out_dir, replace: bool = False):
    """Hold `out_dir` for one run: refuse a folder another run is writing into or one holding
    another run's results (unless `replace`: then they are removed first) or anything else."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise OutputFolderError(f"{out}: exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    fd = os.open(out / LOCK, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = (out / LOCK).read_text().strip() or "another process"
            raise OutputFolderError(
                f"{out}: another run ({holder}) is writing into it; wait for it or choose another folder"
            ) from None
        entries = [p for p in out.iterdir() if p.name != LOCK]
        ours = [p for p in entries if p.name in RUN_MARKERS or p.name == STAGING]
        if entries and not ours:
            raise OutputFolderError(
                f"{out}: holds files that are not a YOWO run's results; choose an empty or new folder"
            )
        if entries and not replace:
            raise OutputFolderError(
                f"{out}: holds an earlier run's results; pass --replace to remove them first, or choose another folder"
            )
        for p in entries:
            shutil.rmtree(p) if p.is_dir() and not p.is_symlink() else p.unlink()
        os.ftruncate(fd, 0)
        os.write(fd, f"pid {os.getpid()}".encode())
        yield out
    finally:
        fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)


def staging_dir(out_dir) -> Path:
    """Where results are written before they are moved into `out_dir`."""
    path = Path(out_dir) / STAGING
    path.mkdir(parents=True, exist_ok=True)
    return path


def publish_staged(out_dir) -> None:
    """Move everything written aside into `out_dir`, each entry whole."""
    staged = Path(out_dir) / STAGING
    if not staged.exists():
        return
    for p in staged.iterdir():
        target = Path(out_dir) / p.name
        if target.is_dir() and not target.is_symlink():
            shutil.rmtree(target)
        os.replace(p, target)
    staged.rmdir()
