"""Packed pixel formats (``acquisition.devices.aravis.pixel_formats``) against an independent packer.

The packers below are written from the layouts' definitions, one bit at a time in pure Python
(the decoder under test works on whole groups with numpy shifts and masks): PFNC "p" as a
little-endian bit stream, GigE Vision "Packed" byte by byte as the GigE Vision 1.x layout places
each bit. Decoding what they pack must give back the very samples packed.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from msflash.acquisition.devices.aravis.pixel_formats import PACKED_FORMATS, packed_size, unpack_pixels
from msflash.acquisition.errors import CameraError


def _bit(value: int, k: int) -> int:
    return (value >> k) & 1


def pack_pfnc(samples: list[int], bits: int) -> bytes:
    """PFNC "p": sample i is stream bits i·bits … i·bits + bits − 1; byte j is stream bits 8j … 8j + 7."""
    stream: list[int] = []
    for value in samples:
        stream.extend(_bit(value, k) for k in range(bits))
    while len(stream) % 8:
        stream.append(0)
    out = bytearray()
    for j in range(0, len(stream), 8):
        out.append(sum(stream[j + k] << k for k in range(8)))
    return bytes(out)


def pack_gev(samples: list[int], bits: int) -> bytes:
    """GigE Vision Packed, two samples in three bytes, each output bit placed by the layout's rule."""
    low = bits - 8  # 4 for 12-bit, 2 for 10-bit
    out = bytearray()
    for p0, p1 in zip(samples[0::2], samples[1::2]):
        byte0 = sum(_bit(p0, k + low) << k for k in range(8))  # p0's top 8 bits
        byte1 = 0
        for k in range(8):
            if k < low:
                byte1 |= _bit(p0, k) << k  # p0's low bits at 0..low-1
            elif 4 <= k < 4 + low:
                byte1 |= _bit(p1, k - 4) << k  # p1's low bits at 4..4+low-1
        byte2 = sum(_bit(p1, k + low) << k for k in range(8))  # p1's top 8 bits
        out += bytes((byte0, byte1, byte2))
    return bytes(out)


def pack(samples: list[int], pixel_format: str) -> bytes:
    layout = PACKED_FORMATS[pixel_format]
    return (pack_pfnc if layout.packing == "pfnc" else pack_gev)(samples, layout.bits)


@st.composite
def frames(draw: st.DrawFn) -> tuple[str, int, int, list[int]]:
    pixel_format = draw(st.sampled_from(sorted(PACKED_FORMATS)))
    layout = PACKED_FORMATS[pixel_format]
    width = layout.group_pixels * draw(st.integers(1, 6))
    height = draw(st.integers(1, 5))
    samples = draw(st.lists(st.integers(0, 2**layout.bits - 1), min_size=width * height, max_size=width * height))
    return pixel_format, width, height, samples


@settings(max_examples=300, deadline=None)
@given(frames())
def test_decoding_gives_back_what_the_independent_packer_packed(frame: tuple[str, int, int, list[int]]) -> None:
    pixel_format, width, height, samples = frame
    data = pack(samples, pixel_format)
    assert len(data) == packed_size(pixel_format, width, height)
    pixels = unpack_pixels(data, pixel_format, width, height)
    assert pixels.dtype == np.uint16 and pixels.shape == (height, width)
    assert pixels.ravel().tolist() == samples
    assert not pixels.flags.writeable


@settings(max_examples=100, deadline=None)
@given(frames(), st.binary(min_size=1, max_size=16))
def test_trailing_bytes_are_ignored(frame: tuple[str, int, int, list[int]], trailer: bytes) -> None:
    pixel_format, width, height, samples = frame
    pixels = unpack_pixels(pack(samples, pixel_format) + trailer, pixel_format, width, height)
    assert pixels.ravel().tolist() == samples


@settings(max_examples=100, deadline=None)
@given(frames(), st.data())
def test_a_truncated_payload_is_refused_with_the_sizes(
    frame: tuple[str, int, int, list[int]], data: st.DataObject
) -> None:
    pixel_format, width, height, samples = frame
    packed = pack(samples, pixel_format)
    cut = data.draw(st.integers(0, len(packed) - 1))
    with pytest.raises(
        CameraError,
        match=rf"camera X: payload of {cut} bytes is too short for {width}x{height} "
        rf"{pixel_format}; expected {len(packed)} bytes",
    ):
        unpack_pixels(packed[:cut], pixel_format, width, height, where="camera X")


@pytest.mark.parametrize(
    ("pixel_format", "width"),
    [("Mono12p", 3), ("Mono10p", 6), ("BayerRG10p", 2), ("Mono12Packed", 5), ("Mono10Packed", 1)],
)
def test_a_width_the_packing_does_not_divide_is_refused(pixel_format: str, width: int) -> None:
    group = PACKED_FORMATS[pixel_format].group_pixels
    with pytest.raises(CameraError, match=rf"cam: width {width} is not a multiple of {group} for {pixel_format}"):
        unpack_pixels(bytes(64), pixel_format, width, 2, where="cam")


def test_unknown_format_and_empty_frame_are_refused() -> None:
    with pytest.raises(CameraError, match="'Mono14p' is not a packed format.*expected one of Mono10p"):
        unpack_pixels(bytes(8), "Mono14p", 2, 2)
    with pytest.raises(CameraError, match="frame size 0x2"):
        unpack_pixels(bytes(8), "Mono12p", 0, 2)


def test_known_bytes_from_the_layouts() -> None:
    """One hand-written group per packing, for a reader checking the bit order by eye."""
    # Mono10p: 0x3FF, 0x000, 0x155, 0x2AA → stream LSB first.
    assert unpack_pixels(bytes([0xFF, 0x03, 0x50, 0x95, 0xAA]), "Mono10p", 4, 1).tolist() == [[0x3FF, 0, 0x155, 0x2AA]]
    # Mono10Packed: 0x3FD and 0x002: byte0 = 0x3FD >> 2, byte1 = 0b01 | 0b10 << 4, byte2 = 0x002 >> 2.
    assert unpack_pixels(bytes([0xFF, 0x21, 0x00]), "Mono10Packed", 2, 1).tolist() == [[0x3FD, 0x002]]


def test_decoded_frames_keep_their_mosaic_and_bits() -> None:
    assert PACKED_FORMATS["BayerGR12p"].cfa == "GRBG" and PACKED_FORMATS["BayerBG10Packed"].cfa == "BGGR"
    assert PACKED_FORMATS["Mono10p"].bits == 10 and PACKED_FORMATS["BayerRG12Packed"].bits == 12


def test_codes_carry_their_bits_on_the_wire() -> None:
    """PFNC codes: bits 16–23 are the bits per pixel on the wire, bit 24 says one channel."""
    for name, layout in PACKED_FORMATS.items():
        assert (layout.pfnc >> 24) == 1, name
        assert ((layout.pfnc >> 16) & 0xFF) * layout.group_pixels == 8 * layout.group_bytes, name


def test_codes_match_aravis_where_aravis_defines_them() -> None:
    """Aravis 0.8's typelib names the Bayer p and Packed formats and Mono*Packed (not Mono10p/Mono12p)."""
    try:
        import gi

        gi.require_version("Aravis", "0.8")
        from gi.repository import Aravis
    except (ImportError, ValueError) as err:
        pytest.skip(f"Aravis unavailable: {err}")
    checked = 0
    for name, layout in PACKED_FORMATS.items():
        if name.startswith("Bayer"):
            cfa, rest = name[5:7], name[7:]
            symbol = f"PIXEL_FORMAT_BAYER_{cfa}_{rest[:2]}{'P' if rest.endswith('p') else '_PACKED'}"
        else:
            symbol = f"PIXEL_FORMAT_MONO_{name[4:6]}{'_P' if name.endswith('p') else '_PACKED'}"
        if hasattr(Aravis, symbol):
            assert getattr(Aravis, symbol) == layout.pfnc, name
            checked += 1
    assert checked == 18  # all but Mono10p and Mono12p, which Aravis 0.8.26 does not define
