"""Photron recordings (``.cihx`` / ``.cih`` + ``.mraw``, :mod:`rspiv.photron`).

Ground truth: recordings written here pixel by pixel from the format's definition (8 bit, 12
bit packed most significant bits first, 16 bit little-endian, a signal on the upper bits) read
back exactly; a real FASTCAM SA-Z recording and a real text header (``tests/data/real``,
pyMRAW's samples, MIT) read with the camera's own figures; and a time-resolved campaign from a
``.cihx`` equal, bit for bit, to the same frames as TIFF files.
"""

from __future__ import annotations

import json
import pathlib

import numpy as np
import pytest
import tifffile
import xarray as xr
from campaign_cases import sequential_config
from rspiv.campaign import Campaign
from rspiv.cli import main
from rspiv.errors import InvalidInputError
from rspiv.io import camera_recording, frame_count, read_image, recording_rate
from rspiv.photron import photron_header, photron_recording, read_photron_frame
from rspiv.synth import particle_sequence

REAL = pathlib.Path(__file__).parent / "data" / "real"


def _pack12(frame: np.ndarray) -> bytes:
    """Two 12 bit pixels in three bytes, most significant bits first."""
    p = frame.astype(np.uint32).ravel()
    p0, p1 = p[0::2], p[1::2]
    out = np.stack([p0 >> 4, ((p0 & 15) << 4) | (p1 >> 8), p1 & 255], axis=1)
    return out.astype(np.uint8).tobytes()


def _write(d: pathlib.Path, frames: np.ndarray, bits: int, *, upper: bool = False,
           colour: str = "Mono", fps: float = 2000.0, name: str = "rec",
           depth: int | None = None, fmt: str = "MRaw") -> pathlib.Path:
    """A text ``.cih`` header and its ``.mraw`` (``frames``: counts of a 12 bit signal; no
    ``.mraw`` for another ``fmt``: frames exported as image files)."""
    n, h, w = frames.shape
    depth = depth or (8 if bits == 8 else 12)
    with open(d / f"{name}.mraw" if fmt == "MRaw" else d / "unused.bin", "wb") as f:
        for fr in frames:
            if bits == 8:
                f.write(fr.astype(np.uint8).tobytes())
            elif bits == 12:
                f.write(_pack12(fr))
            else:
                v = fr.astype(np.uint16) << (4 if upper else 0)
                f.write(v.astype("<u2").tobytes())
    head = d / f"{name}.cih"
    head.write_text(
        "#Camera Information Header\n"
        f"Record Rate(fps) : {fps:g}\nShutter Speed(s) : 1/20000\nTotal Frame : {n}\n"
        f"Start Frame : -10\nImage Width : {w}\nImage Height : {h}\nColor Type : {colour}\n"
        f"Color Bit : {bits}\nFile Format : {fmt}\nEffectiveBit Depth : {depth}\n"
        f"EffectiveBit Side : {'Higher' if upper else 'Lower'}\nCamera Type : test\n"
    )
    return head


@pytest.mark.parametrize(
    "bits, upper, depth", [(8, False, 8), (12, False, 12), (16, False, 12), (16, True, 12),
                           (8, True, 12)]
)  # fmt: skip
def test_frames_written_from_the_definition_read_back_exactly(tmp_path, bits, upper, depth):
    """Every storage; the last, a 12 bit sensor's frames saved in 8 bit pixels (a real
    FASTCAM SA1.1 header says so: ``Color Bit : 8``, ``EffectiveBit Depth : 12``, ``Higher``),
    read as stored."""
    rng = np.random.default_rng(bits + upper)
    top = 256 if bits == 8 else 4096
    frames = rng.integers(0, top, size=(3, 6, 10))
    head = _write(tmp_path, frames, bits, upper=upper, depth=depth)
    rec = photron_recording(head)
    assert (rec.width, rec.height, rec.frames, rec.bits) == (10, 6, 3, bits)
    assert rec.depth == min(depth, bits)
    assert rec.fps == 2000.0 and rec.dt == pytest.approx(5e-4) and rec.start_frame == -10
    assert rec.shutter_s == pytest.approx(5e-5)
    for k in range(3):
        img = read_photron_frame(rec, k)
        assert img.dtype == (np.uint8 if bits == 8 else np.uint16) and img.flags.c_contiguous
        np.testing.assert_array_equal(img, frames[k])
        # the one reader of rspiv, named by the header or the raw file
        np.testing.assert_array_equal(read_image(head, k), frames[k])
        np.testing.assert_array_equal(read_image(tmp_path / "rec.mraw", k), frames[k])
    assert frame_count(head) == frame_count(tmp_path / "rec.mraw") == 3


def test_a_real_cihx_recording():
    """A FASTCAM SA-Z frame (1024 x 80 px at 50,000 fps, a 12 bit signal in 16 bit pixels):
    the header's figures, and counts within 12 bits (read big-endian they would reach 65295).
    Its ``skipFrame`` of 2500 with 4 frames of 400 recorded fits no save step: the time between
    its frames is said to be unknown, not guessed."""
    rec = photron_recording(REAL / "pymraw_beam_1frame.cihx")
    assert (rec.width, rec.height, rec.frames, rec.bits, rec.depth) == (1024, 80, 1, 16, 12)
    assert rec.record_fps == 50000.0 and rec.shutter_s == pytest.approx(5e-6)
    assert np.isnan(rec.fps) and "skipFrame is 2500" in rec.rate_note
    assert recording_rate(rec) == rec.rate_note
    assert rec.camera == "FASTCAM SA-Z type 2100K-M-64GB"
    img = read_image(REAL / "pymraw_beam_1frame.mraw", 0)
    assert img.shape == (80, 1024) and img.dtype == np.uint16
    assert img.max() == 4095 and img.min() == 0 and np.unique(img).size > 1000
    raw = np.fromfile(REAL / "pymraw_beam_1frame.mraw", "<u2").reshape(80, 1024)
    np.testing.assert_array_equal(img, raw)


def test_a_real_text_header(tmp_path):
    """The text ``.cih`` of a FASTCAM SA-Z (12 frames of 896 x 368 px at 60,000 fps, shutter
    1/800000 s, every 36th frame saved: 1,666.7 fps in the file): read with a raw file of its
    size; one byte short is refused in one line."""
    head = tmp_path / "sample.cih"
    head.write_bytes((REAL / "pymraw_sample_60k_16bit.cih").read_bytes())
    with open(tmp_path / "sample.mraw", "wb") as f:
        f.truncate(12 * 896 * 368 * 2)  # sparse: no frame is read
    rec = photron_recording(head)
    assert (rec.width, rec.height, rec.frames, rec.bits, rec.depth) == (896, 368, 12, 16, 12)
    assert rec.record_fps == 60000.0 and rec.step == 36 and rec.shutter_s == pytest.approx(1.25e-6)
    assert rec.fps == pytest.approx(60000.0 / 36) and rec.dt == pytest.approx(6e-4)
    assert recording_rate(rec) == "1666.67 fps (60000 fps recorded, every 36th frame saved)"
    assert rec.start_frame == 49300 and rec.camera == "FASTCAM SA-Z type 2100K-M-64GB"
    with open(tmp_path / "sample.mraw", "r+b") as f:
        f.truncate(12 * 896 * 368 * 2 - 1)
    with pytest.raises(InvalidInputError, match=r"sample.mraw: 7913471 bytes, where sample.cih "
                       r"says 12 frames of 896 x 368 px at 16 bit \(7913472 bytes\)"):  # fmt: skip
        photron_recording(head)


def test_bad_recordings_are_refused_in_one_line(tmp_path):
    frames = np.zeros((2, 4, 6), np.uint16)
    head = _write(tmp_path, frames, 12, colour="Color")
    with pytest.raises(InvalidInputError, match="colour camera's frames"):
        photron_recording(head)
    head = _write(tmp_path, frames, 12, colour="Raw", name="bayer")
    with pytest.raises(InvalidInputError, match="colour type 'Raw'"):
        read_image(head)
    head = _write(tmp_path, frames, 12, name="ok")
    with pytest.raises(InvalidInputError, match=r"ok.mraw: frame 2 out of range \(2 frames\)"):
        read_image(head, 2)
    (tmp_path / "ok.mraw").rename(tmp_path / "lone.mraw")
    with pytest.raises(InvalidInputError, match=r"ok.cih: no raw frames beside it"):
        frame_count(head)
    with pytest.raises(InvalidInputError, match=r"lone.mraw: no Photron header beside it"):
        read_image(tmp_path / "lone.mraw")
    bad = tmp_path / "nowidth.cih"
    bad.write_text("Total Frame : 1\nImage Height : 4\nColor Bit : 8\n")
    (tmp_path / "nowidth.mraw").write_bytes(b"")
    with pytest.raises(InvalidInputError, match="the header has no 'Image Width'"):
        photron_recording(bad)
    (tmp_path / "junk.cihx").write_bytes(b"\0" * 64)
    (tmp_path / "junk.mraw").write_bytes(b"")
    with pytest.raises(InvalidInputError, match=r"junk.cihx: not a Photron .cihx header"):
        photron_recording(tmp_path / "junk.cihx")
    with pytest.raises(InvalidInputError) as info:
        photron_recording(tmp_path / "missing.cihx")
    assert "\n" not in str(info.value) and "no such file" in str(info.value)


SHAPE = (128, 192)
FRAMES = 5


def test_a_time_resolved_campaign_from_a_photron_recording(tmp_path):
    """``[images] multiframe = "rec.cihx"`` pairs the recording's frames as it pairs a stack
    of TIFF files: the same pairs and the same statistics, bit for bit. The run log gives the
    recording's camera and frame rate; a ``[flow] dt`` that is not ``frame_gap`` frames at
    that rate is said loudly (it would scale every velocity), and nothing is said when it is."""
    frames = np.stack(list(particle_sequence(SHAPE, lambda x, y: (1.5 + 0 * y, 0 * y), FRAMES,
                                             seed=2)))  # fmt: skip
    d = tmp_path / "rec"
    d.mkdir()
    head = _write(d, frames, 12, fps=4000.0)
    for k, f in enumerate(frames):
        tifffile.imwrite(d / f"frame_{k:03d}.tif", f)
    said: list[str] = []
    cfg = sequential_config(tmp_path / "a", 2 / 4000.0, multiframe=head, frame_gap=2)
    camp = Campaign(cfg, progress=False, out_dir=tmp_path / "a", log=said.append)
    res = camp.run()
    assert [(p.frame_a, p.frame_b) for p in camp.pairs()] == [(0, 2), (1, 3), (2, 4)]
    assert any("Photron recording" in s and "4000 fps" in s for s in said)
    assert not any("WARNING" in s and "frame rate" in s for s in said)
    ref_cfg = sequential_config(tmp_path / "b", 2 / 4000.0, glob=str(d / "frame_*.tif"),
                                frame_gap=2)  # fmt: skip
    ref = Campaign(ref_cfg, progress=False, out_dir=tmp_path / "b").run()
    np.testing.assert_array_equal(
        res.accumulators["uncorrected"].mean_u, ref.accumulators["uncorrected"].mean_u
    )
    assert np.nanmedian(res.accumulators["uncorrected"].mean_u) == pytest.approx(3.0, abs=0.05)
    # dt of one frame where the pairs are two frames apart: said, with the factor
    said.clear()
    cfg = sequential_config(tmp_path / "c", 1 / 4000.0, multiframe=head, frame_gap=2)
    Campaign(cfg, progress=False, out_dir=tmp_path / "c", log=said.append).run()
    warn = [s for s in said if "WARNING" in s and "frame rate" in s]
    assert len(warn) == 1 and "0.0005 s" in warn[0] and "2x" in warn[0], said
    info = json.loads((tmp_path / "c" / "summary.json").read_text())["recording_file"]
    assert info["fps"] == 4000.0 and info["dt_s"] == pytest.approx(5e-4)
    assert info["camera"] == "test" and "frame rate" in info["warning"]


def test_rspiv_piv_and_check_take_two_frames_of_a_recording(tmp_path, capsys):
    """``rspiv piv rec.cihx --frames I,J`` correlates frames I and J (2 frames of 1.5 px:
    3 px), says how far apart in time they are, and names them in the output; ``rspiv check``
    takes the same; bad ``--frames``, and ``--frames`` with two files, exit 2 in one line."""
    frames = np.stack(list(particle_sequence(SHAPE, lambda x, y: (1.5 + 0 * y, 0 * y), FRAMES,
                                             seed=4)))  # fmt: skip
    head = _write(tmp_path, frames, 16, fps=4000.0)
    out = tmp_path / "f.nc"
    argv = ["piv", str(head), "--frames", "1,3", "--passes", "32x32,16x16", "-o", str(out)]
    assert main(argv) == 0
    said = capsys.readouterr().out
    assert "Photron recording rec.cih: 5 frames of 192 x 128 px, 4000 fps: frames 1 and 3 are " \
           "0.0005 s apart" in said  # fmt: skip
    with xr.open_dataset(out) as ds:
        assert ds.attrs["frame_a"].endswith("rec.cih[1]") and ds.attrs["frame_b"].endswith("[3]")
        u = np.where(ds["valid"].values, ds["u"].values, np.nan)
    assert np.nanmedian(u) == pytest.approx(3.0, abs=0.02)
    assert main(["check", str(head), "--frames", "0,2"]) == 0
    assert "frames 0 and 2 are 0.0005 s apart" in capsys.readouterr().out
    tifffile.imwrite(tmp_path / "a.tif", frames[0])
    for bad, msg in (
        ([str(head), "--frames", "2"], "is not two frame numbers I,J"),
        ([str(head), "--frames", "2,2"], "two different frames"),
        ([str(head), "--frames", "0,9"], "frame 9 out of range (5 frames)"),
        ([str(tmp_path / "a.tif"), str(tmp_path / "a.tif"), "--frames", "0,1"],
         "frames pick two frames of one multi-frame file"),
    ):  # fmt: skip
        assert main(["check", *bad]) == 2
        err = capsys.readouterr().err.strip()
        assert msg in err and "\n" not in err, err


def test_damaged_recordings_are_read_or_refused_in_one_line(tmp_path):
    """Bytes of the real headers overwritten at random (the cine's headers and time stamps, the
    ``.cihx``'s XML; a ``.cih``'s line cut and ended with junk), 300 files with a fixed seed:
    every call returns a frame or raises InvalidInputError in one line; nothing else escapes."""
    rng = np.random.default_rng(0)
    cine = (REAL / "pims_cine_781_2frames.cine").read_bytes()
    cihx = (REAL / "pymraw_beam_1frame.cihx").read_bytes()
    cih = (REAL / "pymraw_sample_60k_16bit.cih").read_text(encoding="latin-1").splitlines()
    mraw = (REAL / "pymraw_beam_1frame.mraw").read_bytes()
    refused = 0
    for k in range(300):
        if k % 3 == 2:
            lines = list(cih)
            i = int(rng.integers(0, len(lines)))
            lines[i] = lines[i][: int(rng.integers(0, len(lines[i]) + 1))] + str(
                rng.choice(["", "9", "-1", "x", "99999999"])
            )
            p = tmp_path / f"f{k}.cih"
            p.write_text("\n".join(lines), encoding="latin-1")
            with open(tmp_path / f"f{k}.mraw", "wb") as f:
                f.truncate(12 * 896 * 368 * 2)
        else:
            b = bytearray(cine if k % 3 == 0 else cihx)
            for _ in range(int(rng.integers(1, 4))):
                b[int(rng.integers(0, 11000))] = int(rng.integers(32, 256))
            p = tmp_path / f"f{k}{'.cine' if k % 3 == 0 else '.cihx'}"
            cut = int(rng.integers(40, len(b))) if k % 3 == 0 and rng.random() < 0.3 else len(b)
            p.write_bytes(bytes(b[:cut]))
            if k % 3 == 1:
                (tmp_path / f"f{k}.mraw").write_bytes(mraw)
        for frame in (0, 1):
            try:
                read_image(p, frame)
            except InvalidInputError as exc:
                assert "\n" not in str(exc) and p.stem in str(exc), repr(str(exc))
                refused += 1
    assert 0 < refused < 600


def test_frames_exported_beside_their_header(tmp_path):
    """Frames exported as TIFF files with the camera's ``.cih`` beside them (PFV's export; a
    real one: PIVsuite's Tububu recording, ``benches/RESULTS.md``): a ``glob`` campaign names
    the camera and checks ``[flow] dt`` against the header's rate; a header of another frame
    size, or two headers, are not used. The header alone reads no frame."""
    frames = np.stack(list(particle_sequence(SHAPE, lambda x, y: (1.5 + 0 * y, 0 * y), FRAMES,
                                             seed=6)))  # fmt: skip
    d = tmp_path / "export"
    d.mkdir()
    for k, f in enumerate(frames):
        tifffile.imwrite(d / f"Img{k + 1:06d}.tif", f)
    head = _write(d, frames[:1], 16, fps=5000.0, name="Img", fmt="Tiff")
    rec = photron_header(head)
    assert rec.data is None and rec.fps == 5000.0 and rec.file_format == "Tiff"
    with pytest.raises(InvalidInputError, match="frames exported as Tiff files: read those"):
        rec.read(0)
    with pytest.raises(InvalidInputError, match=r"Img000001.tif: not a Photron header"):
        photron_header(d / "Img000001.tif")
    with pytest.raises(InvalidInputError, match=r"gone.cih: no such file"):
        photron_header(d / "gone.cih")
    assert camera_recording(d / "Img000001.tif") is None
    with pytest.raises(InvalidInputError, match="saved as 'Tiff', not MRaw: read the exported"):
        read_image(head)
    said: list[str] = []
    cfg = sequential_config(tmp_path / "a", 1 / 5000.0, glob=str(d / "Img*.tif"))
    Campaign(cfg, progress=False, out_dir=tmp_path / "a", log=said.append).run()
    assert any("Photron header Img.cih beside the frames (Tiff files)" in s for s in said)
    assert not any("WARNING" in s and "frame rate" in s for s in said)
    info = json.loads((tmp_path / "a" / "summary.json").read_text())["recording_file"]
    assert info["exported_as"] == "Tiff" and info["dt_s"] == pytest.approx(2e-4)
    said.clear()
    cfg = sequential_config(tmp_path / "b", 1 / 2500.0, glob=str(d / "Img*.tif"))
    Campaign(cfg, progress=False, out_dir=tmp_path / "b", log=said.append).run()
    assert sum("WARNING" in s and "0.5x its true value" in s for s in said) == 1
    # a header of another frame size is said and not used
    _write(d, np.zeros((1, 64, 64)), 16, name="Img", fmt="Tiff")
    said.clear()
    cfg = sequential_config(tmp_path / "c", 1 / 5000.0, glob=str(d / "Img*.tif"))
    Campaign(cfg, progress=False, out_dir=tmp_path / "c", log=said.append).run()
    assert any("Img.cih beside the frames is not used: it describes frames of 64 x 64 px, "
               "these are 192 x 128" in s for s in said)  # fmt: skip
    assert "recording_file" not in json.loads((tmp_path / "c" / "summary.json").read_text())
