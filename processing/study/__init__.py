"""Simulation studies of the paper (Blasinski & Farrell, ICCP 2017, Section 5), in pure numpy.

- :mod:`processing.study.illuminants`: the smoothest non-negative spectrum with a given CIE xy
  and the paper's grid of feasible chromaticities.
- :mod:`processing.study.table1`: Table 1 (accuracy vs number of LEDs over 34 cameras and the
  feasible illuminants).
- :mod:`processing.study.surfaces`: Fig. 5 (accuracy vs number of distinct surfaces).

Nothing here reads or writes files beyond the shipped data loaders; the CLI
(``acquisition.cli_study``) writes the results.
"""
