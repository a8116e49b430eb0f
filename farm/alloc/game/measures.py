"""The measures of an episode and of a step, by name (docs/model.md section 5).

MEASURES, an episode's: return, eliminated, breached (the reward sum, the mass eliminated and
breached), coverage (the share of the intruder mass sharing a cell with defenders, averaged over
the episode's steps), engaged (engaged cells per step), defenders_per_engaged (defenders per
engaged cell, over the steps with any), length (steps).
STEP_MEASURES, a step's: coverage, engaged_cells, defenders_per_engaged.
"""

__all__ = ["MEASURES", "STEP_MEASURES"]

MEASURES = ("return", "eliminated", "breached", "coverage", "engaged", "defenders_per_engaged", "length")
STEP_MEASURES = ("coverage", "engaged_cells", "defenders_per_engaged")
