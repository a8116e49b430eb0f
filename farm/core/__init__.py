"""The floor every other part of farm stands on: the errors it reports in one line
(errors), atomic writes of result files (output), progress bars (progress), figures
(plots), config loading (config) and the one mean ± 95% CI of every table (stats).
Imports workers only."""
