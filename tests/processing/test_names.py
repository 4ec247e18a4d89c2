"""The one "did you mean" (processing/names.py)."""

from __future__ import annotations

from msflash.processing.names import LIST_AT_MOST, close_names, unknown_name


def test_suggestions_ignore_case_and_prefer_what_the_name_begins() -> None:
    assert close_names("tikonov", ["lstsq", "nonneg", "roughness", "tikhonov"]) == ["tikhonov"]
    assert close_names("D66", ["A", "D50", "D60", "D65"])[:2] == ["D65", "D60"]
    assert close_names("under", ["tungsten", "underwater", "underwater_ocean"])[0] == "underwater"
    assert close_names("NIKOND100", ["NikonD100", "NikonD1"])[0] == "NikonD100"
    assert close_names("zzz", ["tungsten", "daylight"]) == []


def test_one_line_with_the_suggestion_first_and_a_long_list_cut() -> None:
    many = [f"name{i}" for i in range(LIST_AT_MOST + 10)] + ["tungsten"]
    line = unknown_name("--ambient", "tungstn", many, "a CSV file")
    assert "\n" not in line
    assert line.startswith("--ambient 'tungstn': unknown; did you mean 'tungsten'? expected one of name0, ")
    assert line.endswith(f"… ({len(many)} names) or a CSV file")
    nothing_close = unknown_name("--ambient", "qqq", many)
    assert "did you mean" not in nothing_close and "tungsten" in nothing_close  # then every name is listed
