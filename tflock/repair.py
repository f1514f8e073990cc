"""``tflock repair``: a recording without its footer (a run killed by SIGKILL, out of memory or a power loss) made
complete again.

A run writes its ``.rrd`` as it goes and adds the footer (the index ``rerun rrd verify`` checks) when it ends; a run
that is killed leaves every message written so far but no footer, and the last message may be cut. The file is
rewritten through Rerun's own reader and writer, ``rerun rrd merge --continue-on-error`` (the ``rerun`` binary that
comes with rerun-sdk): it decodes every whole message, skips a cut one, keeps both stores (the recording and its
default blueprint, with their ids) and writes a complete file with its footer. The rewrite goes to a temporary file
beside the destination, must pass ``rerun rrd verify``, and is then renamed into place, so the original is replaced
only by a verified file. The recording's lock (:mod:`tflock.outputs`) is held throughout: a file that a live run is
still writing is refused.
"""

from __future__ import annotations

import os
import subprocess
from dataclasses import dataclass
from pathlib import Path

from tflock.outputs import Outputs, claim, lock
from tflock.record import RecordingSummary, read_recording, rerun_executable, verify_recording

#: the first bytes of every .rrd file (Rerun's stream header)
RRD_MAGIC = b"RRF2"


class RepairError(ValueError):
    """A file that cannot be repaired (the message is one line)."""


@dataclass
class RepairResult:
    """What :func:`repair_recording` did: the complete file (`path`), whether it rewrote anything, and what the
    file holds (None when it is not a tflock recording)."""

    path: Path
    rewritten: bool
    summary: RecordingSummary | None


def _summary(path: Path) -> RecordingSummary | None:
    try:
        return read_recording(path)
    except ValueError:  # a Rerun recording, not tflock's
        return None


def repair_recording(path: Path, out: Path | None = None, *, overwrite: bool = False) -> RepairResult:
    """Make `path` a complete recording: in place, or into `out` (`overwrite`: replace an earlier file there).

    A file that verifies already is left as it is. Raises RepairError for a file that is not an .rrd or holds
    nothing to recover, OSError for a path that cannot be read or written or that a run is writing."""
    path = Path(path)
    if not path.is_file():
        raise RepairError(f"recording not found: {path}" if not path.exists() else f"{path} is not a file")
    with open(path, "rb") as file:
        head = file.read(len(RRD_MAGIC))
    if not head:
        raise RepairError(f"{path} is empty: its run was stopped before it wrote anything; nothing to recover")
    if head != RRD_MAGIC:
        raise RepairError(f"{path} is not a Rerun recording (it does not start with {RRD_MAGIC.decode()})")
    held = Outputs()
    try:
        held.locks.append(lock(path))
        destination = path
        if out is not None and Path(out).resolve() != path.resolve():
            destination = Path(out)
            claim(destination, "recording", overwrite=overwrite, into=held)
        if verify_recording(path):
            if destination != path:
                raise RepairError(f"{path} is complete already (rerun rrd verify passes); copy it if you need "
                                  f"it at {destination}")
            return RepairResult(path, False, _summary(path))
        _rewrite(path, destination)
        return RepairResult(destination, True, _summary(destination))
    finally:
        held.release()


def _rewrite(source: Path, destination: Path) -> None:
    """``rerun rrd merge`` `source` into a temporary file beside `destination`, verify it, rename it into place."""
    temporary = destination.with_name(f".{destination.name}.repair-{os.getpid()}.tmp")
    try:
        done = subprocess.run([*rerun_executable(), "rrd", "merge", "--continue-on-error", str(source), "-o",
                               str(temporary)], stdin=subprocess.DEVNULL, capture_output=True, text=True,
                              check=False, env={**os.environ, "RUST_LOG": "error"})
        if done.returncode != 0 or not temporary.is_file():
            last = (done.stderr.strip().splitlines() or ["no message"])[-1]
            raise RepairError(f"rerun rrd merge could not rewrite {source}: {last}")
        if not verify_recording(temporary):
            raise RepairError(f"{source} holds no readable recording: nothing to recover")
        os.replace(temporary, destination)
    finally:
        temporary.unlink(missing_ok=True)
