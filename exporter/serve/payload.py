"""One answer of the DB mode as it is cached and sent: the bytes stored once (gzip-compressed when that pays),
strong ETags for each encoding, and the two request headers that choose between them (Accept-Encoding,
If-None-Match)."""

from __future__ import annotations

import gzip
import hashlib
from dataclasses import dataclass

#: Keep a gzip variant only when it is at least this much smaller than the bytes (else gzip costs the client
#: CPU for nothing).
GZIP_MIN_SAVING = 0.10
#: Level 6 packs glbs to 25-34 % of their size (flat shading repeats normals and colours per vertex) at about
#: 50 MB/s; level 1 is twice as fast for 6 % more bytes.
GZIP_LEVEL = 6


@dataclass(frozen=True)
class Payload:
    """One cached answer, stored once: gzip-compressed when that pays (browsers all accept gzip; a client that
    does not gets it decompressed per request), else as is; strong ETags for both encodings. Storing one variant
    keeps a city's tiles in the cache budget: the Liechtenstein tileset is 234 MB raw but 65 MB gzipped, and a
    cache smaller than what a client cycles through turns every "warm" request into a rebuild (LRU thrash)."""

    stored: bytes
    gzipped: bool
    etag: str
    media_type: str

    @property
    def gzip_etag(self) -> str:
        return self.etag[:-1] + '-gzip"'

    @property
    def gzip(self) -> bytes | None:
        return self.stored if self.gzipped else None

    @property
    def body(self) -> bytes:
        return gzip.decompress(self.stored) if self.gzipped else self.stored

    @property
    def size(self) -> int:
        """What it costs the cache: the stored bytes plus a rough overhead per entry."""
        return len(self.stored) + 200


def make_payload(body: bytes, media: str, min_saving: float = GZIP_MIN_SAVING) -> Payload:
    packed = gzip.compress(body, GZIP_LEVEL, mtime=0)
    keep = len(packed) <= (1.0 - min_saving) * len(body)
    return Payload(packed if keep else body, keep, f'"{hashlib.sha256(body).hexdigest()[:32]}"', media)


def accepts_gzip(header: str | None) -> bool:
    """Accept-Encoding allows gzip (explicitly, or through ``*``) with q > 0."""
    if not header:
        return False
    q_gzip = q_star = None
    for item in header.split(","):
        name, _, params = item.partition(";")
        name = name.strip().lower()
        q = 1.0
        for p in params.split(";"):
            k, _, v = p.partition("=")
            if k.strip().lower() == "q":
                try:
                    q = float(v)
                except ValueError:
                    q = 0.0
        if name in ("gzip", "x-gzip"):
            q_gzip = q
        elif name == "*":
            q_star = q
    chosen = q_gzip if q_gzip is not None else q_star
    return chosen is not None and chosen > 0


def etag_matches(header: str | None, etag: str) -> bool:
    """If-None-Match (weak comparison, RFC 9110 13.1.2) against our strong ETag."""
    if not header:
        return False
    tags = [t.strip() for t in header.split(",")]
    return any(t == "*" or t.removeprefix("W/") == etag for t in tags)
