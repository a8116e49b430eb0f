"""Files that carry their own checksum: a first line naming what the file is, a JSON header line
(the SHA-256 and length of what follows, and what the writer adds to it), then the payload. seal
makes one, unseal reads one back or says in a few words why it cannot (SealProblem); file_sha256
is the checksum of a file another one names. A pretraining's iteration files and a checkpoint's
RunState are sealed (farm.alloc.training)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

__all__ = ["SealProblem", "seal", "unseal", "is_sealed", "file_sha256"]


class SealProblem(Exception):
    """Why a sealed file cannot be read, in a few words: "no checksum" (not a sealed file: one
    written without a checksum), "its header" or "fails its checksum" (damaged)."""


def seal(magic: bytes, payload: bytes, **header) -> bytes:
    """The bytes of a sealed file: magic (one line, ending in a newline), a JSON line of header
    with the payload's "sha256" and "bytes" added, then payload."""
    if not magic.endswith(b"\n") or magic.count(b"\n") != 1:
        raise ValueError("magic: one line, ending in a newline")
    line = json.dumps({**header, "sha256": hashlib.sha256(payload).hexdigest(), "bytes": len(payload)})
    return magic + line.encode() + b"\n" + payload


def is_sealed(data: bytes, magic: bytes) -> bool:
    """Whether data starts as a sealed file of magic does (its header unread)."""
    return data.startswith(magic)


def unseal(data: bytes, magic: bytes) -> tuple[dict, memoryview]:
    """(the header, the payload) of a sealed file's bytes whose payload has the header's length
    and checksum; SealProblem otherwise: without magic ("no checksum"), a header that is not one
    ("its header"), a payload of another length or checksum ("fails its checksum")."""
    if not is_sealed(data, magic):
        raise SealProblem("no checksum")
    end = data.find(b"\n", len(magic))
    try:
        header = json.loads(data[len(magic): end]) if end > 0 else None
    except (UnicodeDecodeError, ValueError):
        header = None
    if not isinstance(header, dict) or not isinstance(header.get("sha256"), str) \
            or not isinstance(header.get("bytes"), int):
        raise SealProblem("its header")
    payload = memoryview(data)[end + 1:]
    if len(payload) != header["bytes"] or hashlib.sha256(payload).hexdigest() != header["sha256"]:
        raise SealProblem("fails its checksum")
    return header, payload


def file_sha256(path: Path) -> str:
    """The SHA-256 of a file's bytes, read in chunks."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()
