"""An independent writer of spectrometer exports, as the instruments' own programs write them.

Nothing here imports msflash's readers: the exports are built from physics (a CCD's
pixel-to-wavelength polynomial, an instrument response, a fixed offset plus a dark current that
grows with the integration time, shot and read noise averaged over scans) and written in each
program's layout, with its quirks (OceanView's Java exponents ``1.000000E-1``; decimal commas in
a European locale; AvaSoft's ``Wave ;Sample ;Dark`` columns and ``[counts]`` unit row; SpectraWiz's
quoted header and ``1.2112E+002`` three-digit exponents; Thorlabs' ``#Key;value`` lines and
seconds; BOM; CRLF). The header spellings follow public exports of each program (see
``calibration/spectrometer_header.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

FORMATS = ("oceanview", "spectrasuite", "avasoft", "spectrawiz", "thorlabs", "plain")


@dataclass(frozen=True)
class Instrument:
    """A CCD spectrometer: its grid, response, offset and dark current."""

    wavelengths_nm: np.ndarray
    """Pixel centres (a cubic pixel-to-wavelength polynomial: not uniform)."""
    response: np.ndarray
    """Counts per second per unit spectral irradiance, per pixel."""
    offset: float
    """Fixed offset (ADC bias), counts."""
    dark_rate: np.ndarray
    """Dark current per pixel, counts per second."""
    read_noise: float
    """Counts, per scan."""

    @classmethod
    def typical(cls, seed: int = 0, start: float = 340.0, stop: float = 800.0, pixels: int = 1400) -> Instrument:
        rng = np.random.default_rng(seed)
        x = np.arange(pixels, dtype=float) / (pixels - 1)
        wavelengths = start + (stop - start) * (x + 0.04 * x * (1 - x) - 0.02 * x**2 * (1 - x))
        # A grating's blaze and a silicon detector's QE: a broad hump, 4× from its edges to its peak.
        response = 4000.0 * (0.25 + np.exp(-0.5 * ((wavelengths - 560.0) / 120.0) ** 2))
        dark_rate = 2000.0 * (1 + 0.05 * rng.standard_normal(pixels))  # 20 counts at 10 ms
        return cls(wavelengths, response, 80.0, dark_rate, 2.0)

    def counts(
        self, irradiance: np.ndarray | None, time_s: float, averages: int, rng: np.random.Generator
    ) -> np.ndarray:
        """One export's counts: offset + dark current · t + response · irradiance · t, with noise.

        ``irradiance`` on :attr:`wavelengths_nm` (None: the shutter closed, a dark).
        """
        signal = self.dark_rate * time_s + (0.0 if irradiance is None else self.response * irradiance * time_s)
        shot = np.sqrt(np.maximum(signal, 0.0))
        noise = rng.normal(0.0, 1.0, signal.size) * np.hypot(shot, self.read_noise) / np.sqrt(averages)
        return self.offset + signal + noise


def _java_exponent(value: float) -> str:
    """``1.000000E-1``: Java's %E-like text as OceanView writes it."""
    mantissa, exponent = f"{value:.6E}".split("E")
    return f"{mantissa}E{int(exponent)}"


def _windows_exponent(value: float) -> str:
    """``1.2112E+002``: the three-digit exponent of Windows' C runtime (SpectraWiz)."""
    mantissa, exponent = f"{value:.4E}".split("E")
    return f"{mantissa}E{exponent[0]}{abs(int(exponent)):03d}"


def _comma(text: str, decimal_comma: bool) -> str:
    return text.replace(".", ",") if decimal_comma else text


def export_text(
    form: str,
    wavelengths: np.ndarray,
    counts: np.ndarray,
    time_s: float | None,
    averages: int = 1,
    *,
    decimal_comma: bool = False,
    stored_dark: np.ndarray | None = None,
    name: str = "led",
) -> str:
    """The export text of ``counts`` in program ``form``'s layout (one of :data:`FORMATS`).

    ``time_s`` None writes no integration time (a plain file without one); ``stored_dark`` fills
    AvaSoft's Dark column (zeros otherwise).
    """
    dc = decimal_comma
    if form == "oceanview":
        head = [
            f"Data from {name}__0__10-15-23-123.txt Node",
            "",
            "Date: Tue Mar 12 10:15:23 CET 2024",
            "User: lab",
            "Spectrometer: FLMS01234",
            "Trigger mode: 0",
            f"Integration Time (sec): {_comma(_java_exponent(time_s or 0.0), dc)}",
            f"Scans to average: {averages}",
            "Electric dark correction enabled: false",
            "Nonlinearity correction enabled: false",
            "Boxcar width: 0",
            "XAxis mode: Wavelengths",
            f"Number of Pixels in Spectrum: {wavelengths.size}",
            ">>>>>Begin Spectral Data<<<<<",
        ]
        rows = [_comma(f"{w:.2f}\t{c:.2f}", dc) for w, c in zip(wavelengths, counts, strict=True)]
        return "\n".join([*head, *rows, ">>>>>End Spectral Data<<<<<"]) + "\n"
    if form == "spectrasuite":
        usec = int(round((time_s or 0.0) * 1e6))
        head = [
            "SpectraSuite Data File",
            "++++++++++++++++++++++++++++++++++++",
            "Date: Tue Mar 12 10:15:23 CET 2024",
            "User: lab",
            "Dark Spectrum Present: No",
            "Reference Spectrum Present: No",
            "Number of Sampled Component Spectra: 1",
            "Spectrometers: USB4F01234",
            f"Integration Time (usec): {usec} (USB4F01234)",
            f"Spectra Averaged: {averages} (USB4F01234)",
            "Boxcar Smoothing: 0 (USB4F01234)",
            "Correct for Electrical Dark: No (USB4F01234)",
            "Strobe/Lamp Enabled: No (USB4F01234)",
            "Correct for Detector Non-linearity: No (USB4F01234)",
            "Correct for Stray Light: No (USB4F01234)",
            f"Number of Pixels in Processed Spectrum: {wavelengths.size}",
            ">>>>>Begin Processed Spectral Data<<<<<",
        ]
        rows = [f"{w:.2f}\t{c:.3f}" for w, c in zip(wavelengths, counts, strict=True)]
        return "\n".join([*head, *rows, ">>>>>End Processed Spectral Data<<<<<"]) + "\n"
    if form == "avasoft":
        dark = np.zeros_like(counts) if stored_dark is None else stored_dark
        head = [
            name,
            f"Integration time [ms]: {_comma(f'{1e3 * (time_s or 0.0):.3f}', dc)}",
            f"Averaging Nr. [scans]: {averages}",
            "Smoothing Nr. [pixels]: 0",
            "Data measured with spectrometer [name]: 1102107U1",
            "Wave   ;Sample   ;Dark     ;Reference;Scope Corrected for Dark",
            "[nm]   ;[counts] ;[counts] ;[counts] ;[counts]",
            "",
        ]
        rows = [
            _comma(f"{w:8.3f};{c:9.3f};{d:9.3f};{0.0:9.3f};{c - d:9.3f}", dc)
            for w, c, d in zip(wavelengths, counts, dark, strict=True)
        ]
        return "\n".join([*head, *rows]) + "\n"
    if form == "spectrawiz":
        ms = 1e3 * (time_s or 0.0)
        top = int(np.argmax(counts))
        head = [
            f'" File: C:\\SpectraWiz\\data\\{name}.SSM',
            f'" SCOPE->  Wave:{wavelengths[top]:.2f}nm  Pix:{top}  Val:{counts[top]:.3f}  Time:{ms:g}ms  Avg:{averages}  '
            "Sm:0  Sg:0  Tc:off  SNAP  Xt:3  Ch:1  Xtrig",
        ]
        rows = [f" {w:.2f}  {_windows_exponent(c)}" for w, c in zip(wavelengths, counts, strict=True)]
        return "\n".join([*head, *rows]) + "\n"
    if form == "thorlabs":
        head = [
            "#[SpectrumHeader]",
            "#Date;20240312",
            "#Time;10152312",
            "#GMTTime;09152312",
            "#XAxisUnit;nm_air",
            "#YAxisUnit;intensity",
            f"#Average;{0 if averages == 1 else averages}",
            "#RollingAverage;0",
            "#SpectrumSmooth;0",
            "#SSmoothParam1;0",
            "#SSmoothParam2;0",
            "#SSmoothParam3;0",
            "#SSmoothParam4;0",
            f"#IntegrationTime;{_comma(f'{time_s or 0.0:.6f}', dc)}",
            "#TriggerMode;0",
            "#InterferometerSerial;M00463105",
            "#Source",
            "#AirMeasureOpt;0",
            f"#Length;{wavelengths.size}",
            "#Model;CCS200",
            "#Type;emission",
            "#Name;" + name,
            '#Comment; ""',
            "#[Data]",
        ]
        rows = [_comma(f"{w:.9e};{c:.9e}", dc) for w, c in zip(wavelengths, counts, strict=True)]
        return "\n".join([*head, *rows, "#[EndOfFile]"]) + "\n"
    if form == "plain":
        head = [f"# {name}, exported by a lab script"]
        if time_s is not None:
            head.append(f"# integration_time_ms: {1e3 * time_s:g}")
        head += [f"# averages: {averages}", "wavelength_nm,counts"]
        rows = [f"{w:.4f},{c:.3f}" for w, c in zip(wavelengths, counts, strict=True)]
        return "\n".join([*head, *rows]) + "\n"
    raise ValueError(f"unknown format {form!r}; expected one of {FORMATS}")


def encoded(text: str, *, bom: bool = False, crlf: bool = False, encoding: str = "utf-8") -> bytes:
    """The file's bytes: Windows line endings and a byte-order mark where the program writes them."""
    if crlf:
        text = text.replace("\n", "\r\n")
    data = text.encode(encoding)
    if bom and encoding == "utf-8":
        data = b"\xef\xbb\xbf" + data
    return data
