"""Simulation studies of the paper (Blasinski & Farrell, ICCP 2017, Section 5), in pure numpy.

- :mod:`lab.study.illuminants`: the smoothest non-negative spectrum with a given CIE xy
  and the paper's grid of feasible chromaticities.
- :mod:`lab.study.table1`: Table 1 (accuracy vs number of LEDs over 34 cameras and the
  feasible illuminants).
- :mod:`lab.study.surfaces`: Fig. 5 (accuracy vs number of distinct surfaces).
- :mod:`lab.study.cameras`: Figs. 6–7 (camera invariance vs number of LEDs; error over the xy grid).
- :mod:`lab.study.noisy`: noisy rendered frame stacks through the app's estimation path.
- :mod:`lab.study.failure`: where estimates fail and whether their reliability signals warn.
- :mod:`lab.study.pareto`: accuracy against time per solver × pixel subsampling.
- :mod:`lab.study.local`: local against global ambient estimation (issue 9, ``msflash local-study``).

The processing core never imports this package (an import-linter contract in ``pyproject.toml``).

Nothing here reads or writes files beyond the shipped data loaders; the CLIs
(``lab.cli_study``, ``lab.cli_local``) write the results.
"""
