"""Phantom recordings (``.cine``, :mod:`rspiv.phantom`).

Ground truth: cine files written here from the format's layout (8 and 16 bit, rows bottom-up
or top-down, frame time stamps or only the setup's rate) read back exactly, with the frame
rate of their time stamps; a real Phantom cine (``tests/data/real``, PIMS' sample, BSD) saved
with decimation, whose frames are 9 kHz apart while the camera ran at 90 kHz; and a
time-resolved campaign from a ``.cine`` equal, bit for bit, to the same frames as TIFF files.
"""

from __future__ import annotations

import json
import pathlib
import struct

import numpy as np
import pytest
import tifffile
from campaign_cases import sequential_config
from rspiv.campaign import Campaign
from rspiv.errors import InvalidInputError
from rspiv.io import camera_recording, frame_count, read_image
from rspiv.phantom import phantom_recording, read_phantom_frame
from rspiv.synth import particle_sequence

REAL = pathlib.Path(__file__).parent / "data" / "real"
SETUP_LENGTH = 200


def _write(path: pathlib.Path, frames: np.ndarray, bits: int = 16, *, fps: float = 5000.0,
           stamps: bool = True, top_down: bool = False, compression: int = 0,
           image_bits: int | None = None, setup_rate: int = 4000) -> pathlib.Path:
    """A cine of ``frames`` (n, h, w) from the layout of the module docs: time stamps ``k /
    fps`` (block 1002) unless not ``stamps``; ``image_bits`` the bits per pixel said in each
    frame's size (a packed frame), ``setup_rate`` the setup's 16-bit frame rate."""
    n, h, w = frames.shape
    tag = 8 + 8 * n if stamps else 0
    off_setup = 44 + 40
    off_offsets = off_setup + SETUP_LENGTH + tag
    size = w * h * (image_bits or bits) // 8
    first_frame = off_offsets + 8 * n
    out = bytearray(struct.pack("<2sHHHiIiIIIIQ", b"CI", 44, compression, 1, -n, n, -n, n,
                                44, off_setup, off_offsets, 0))  # fmt: skip
    out += struct.pack("<IiiHHIIiiII", 40, w, -h if top_down else h, 1, bits, 0, size, 0, 0,
                       0, 1 << 12)  # fmt: skip
    setup = bytearray(SETUP_LENGTH)
    struct.pack_into("<H", setup, 0, setup_rate)
    struct.pack_into("<2sH", setup, 140, b"ST", SETUP_LENGTH)
    out += setup
    if stamps:
        # seconds in the upper 32 bits, 2^-32 s in the lower (the frames within one second)
        frac = np.round(np.arange(n) / fps * 2**32).astype(np.uint64)
        ticks = (np.uint64(1_700_000_000) << np.uint64(32)) + frac
        out += struct.pack("<IHH", tag, 1002, 0) + ticks.astype("<u8").tobytes()
    out += struct.pack(f"<{n}q", *[first_frame + k * (8 + size) for k in range(n)])
    for fr in frames:
        rows = fr if top_down else fr[::-1]
        data = rows.astype(np.uint8 if bits == 8 else "<u2").tobytes()[:size]
        out += struct.pack("<II", 8, size) + data.ljust(size, b"\0")
    path.write_bytes(bytes(out))
    return path


@pytest.mark.parametrize("bits, top_down", [(8, False), (16, False), (16, True)])
def test_frames_written_from_the_layout_read_back_exactly(tmp_path, bits, top_down):
    rng = np.random.default_rng(bits)
    frames = rng.integers(0, 256 if bits == 8 else 4096, size=(4, 6, 10))
    f = _write(tmp_path / "rec.cine", frames, bits, top_down=top_down)
    rec = phantom_recording(f)
    assert (rec.width, rec.height, rec.frames, rec.bits, rec.depth) == (10, 6, 4, bits,
                                                                        min(bits, 12))  # fmt: skip
    assert rec.fps == pytest.approx(5000.0, rel=1e-6) and rec.fps_source == "time stamps"
    assert rec.first_image == -4 and camera_recording(f) == rec
    for k in range(4):
        img = read_phantom_frame(rec, k)
        assert img.dtype == (np.uint8 if bits == 8 else np.uint16) and img.flags.c_contiguous
        np.testing.assert_array_equal(img, frames[k])
        np.testing.assert_array_equal(read_image(f, k), frames[k])
    assert frame_count(f) == 4


def test_without_time_stamps_the_setup_rate_is_used(tmp_path):
    frames = np.zeros((2, 4, 4), np.uint16)
    rec = phantom_recording(_write(tmp_path / "a.cine", frames, stamps=False))
    assert rec.fps == 4000.0 and rec.fps_source == "setup" and rec.dt == 2.5e-4
    # 65535: the setup says "see the 32-bit rate", which is not read here
    rec = phantom_recording(_write(tmp_path / "b.cine", frames, stamps=False, setup_rate=65535))
    assert np.isnan(rec.fps) and rec.fps_source == "" and np.isnan(rec.dt)


def test_a_real_cine_saved_with_decimation():
    """PIMS' ``cine_781.cine`` (Phantom Camera Control 3.3.781, recorded at 90,000 fps and
    saved every 10th frame: "actual fps 9,000", its author wrote), its first 2 frames: the
    time stamps give 9,003.2 fps (111.071 us; the full file's 14 intervals the same), within
    0.04 % of the nominal rate, not the 90 kHz the camera ran at; the sensor's 12 bits, 256 x
    256 px, rows stored bottom-up read top-down (the needle the frames show enters from below).
    PIMS' other sample (``cine_legacy.cine``, not vendored) gives 35,087.9 fps from its time
    stamps where its setup says 35,087."""
    rec = phantom_recording(REAL / "pims_cine_781_2frames.cine")
    assert (rec.width, rec.height, rec.frames, rec.bits, rec.depth) == (256, 256, 2, 16, 12)
    assert rec.fps_source == "time stamps" and rec.fps == pytest.approx(9003.2, rel=1e-5)
    assert rec.fps == pytest.approx(9000.0, rel=4e-4)
    assert rec.first_image == -5417
    img = read_image(REAL / "pims_cine_781_2frames.cine", 0)
    assert img.dtype == np.uint16 and 0 < img.min() and img.max() < 4096
    # the needle: a dark column in the bottom rows, none in the top rows
    bottom, top = img[-20:, 100:160].mean(axis=0), img[:20, 100:160].mean(axis=0)
    assert bottom.min() < 0.3 * np.median(bottom) and top.min() > 0.7 * np.median(top)


def test_bad_cines_are_refused_in_one_line(tmp_path):
    frames = np.zeros((2, 4, 6), np.uint16)
    cases = [
        (dict(compression=1), "JPEG-compressed cine"),
        (dict(compression=2), "uninterpolated raw"),
        (dict(bits=24), "interpolated colour"),
        (dict(image_bits=12), "packed at 12 bit: save the cine unpacked"),
    ]
    for k, (kw, msg) in enumerate(cases):
        f = _write(tmp_path / f"bad{k}.cine", frames, **kw)
        with pytest.raises(InvalidInputError, match=msg) as info:
            read_image(f, 0)
        assert "\n" not in str(info.value) and f"bad{k}.cine" in str(info.value)
    with pytest.raises(InvalidInputError, match=r"gone.cine: no such file"):
        phantom_recording(tmp_path / "gone.cine")
    (tmp_path / "junk.cine").write_bytes(b"\0" * 100)
    with pytest.raises(InvalidInputError, match="not a Phantom cine file"):
        frame_count(tmp_path / "junk.cine")
    f = _write(tmp_path / "ok.cine", frames)
    with pytest.raises(InvalidInputError, match=r"ok.cine: frame 2 out of range \(2 frames\)"):
        read_image(f, 2)
    cut = tmp_path / "cut.cine"
    cut.write_bytes(f.read_bytes()[:-10])
    with pytest.raises(InvalidInputError, match=r"cut.cine: frame 1 is cut short"):
        read_image(cut, 1)


def test_a_time_resolved_campaign_from_a_cine(tmp_path):
    """``[images] multiframe = "rec.cine"`` pairs the frames as a stack of TIFF files does:
    the same statistics, bit for bit; the run log gives the frame rate of the time stamps, and
    a ``[flow] dt`` of another rate is said loudly."""
    frames = np.stack(list(particle_sequence((128, 192), lambda x, y: (1.5 + 0 * y, 0 * y), 4,
                                             seed=3)))  # fmt: skip
    d = tmp_path / "rec"
    d.mkdir()
    cine = _write(d / "rec.cine", frames, fps=2000.0)
    for k, f in enumerate(frames):
        tifffile.imwrite(d / f"frame_{k:03d}.tif", f)
    config = sequential_config

    said: list[str] = []
    res = Campaign(config(tmp_path / "a", 5e-4, multiframe=cine), progress=False,
                   out_dir=tmp_path / "a", log=said.append).run()  # fmt: skip
    ref = Campaign(config(tmp_path / "b", 5e-4, glob=str(d / "frame_*.tif")), progress=False,
                   out_dir=tmp_path / "b").run()  # fmt: skip
    np.testing.assert_array_equal(
        res.accumulators["uncorrected"].mean_u, ref.accumulators["uncorrected"].mean_u
    )
    assert any("Phantom recording rec.cine: 4 frames of 192 x 128 px" in s and "2000 fps" in s
               for s in said)  # fmt: skip
    assert not any("WARNING" in s and "frame rate" in s for s in said)
    said.clear()
    Campaign(config(tmp_path / "c", 1e-3, multiframe=cine), progress=False,
             out_dir=tmp_path / "c", log=said.append).run()  # fmt: skip
    assert sum("WARNING" in s and "frame rate" in s and "0.5x" in s for s in said) == 1
    info = json.loads((tmp_path / "c" / "summary.json").read_text())["recording_file"]
    assert info["fps"] == pytest.approx(2000.0) and "warning" in info
