"""The ambient-estimation harness of issue 17: measured spectra the simulator does not use, the
authors' estimator and plain least squares as baselines, a tuning and a held-out split
(``python -m tests.harness.ambient``; docs/ambient-harness.md)."""
