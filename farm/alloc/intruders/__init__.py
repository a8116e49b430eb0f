"""The intruders' policies behind one interface: the drift law (drift.py), the adaptive
heuristics (one file each), trained ones (learned.py), mixtures (mixture.py) and the search
against a model of the allocators (searching.py), registered in farm.alloc.game.registry.INTRUDERS.

Adding one is one file holding a subclass of base.IntruderPolicy (its `routing(D, I)`) and one
`register_intruders` line below.
"""

from farm.alloc.game.registry import INTRUDERS, Entry, Spec
from farm.alloc.intruders.drift import Drift
from farm.alloc.intruders.fewest_ahead import FewestAhead
from farm.alloc.intruders.learned import LearnedIntruders
from farm.alloc.intruders.least_defended import LeastDefended
from farm.alloc.intruders.mixture import IntruderMixture
from farm.alloc.intruders.play import configured_intruders, intruder_move
from farm.alloc.intruders.searching import SearchingIntruders
from farm.alloc.intruders.split_away import SplitAway

__all__ = ["INTRUDERS", "Entry", "Spec", "register_intruders", "unregister_intruders", "intruder_entry",
           "intruder_names", "make_intruders", "configured_intruders", "intruder_move"]

register_intruders = INTRUDERS.register
unregister_intruders = INTRUDERS.unregister
intruder_entry = INTRUDERS.entry
intruder_names = INTRUDERS.names
make_intruders = INTRUDERS.make

register_intruders("drift", Drift.make, kind="law")
register_intruders("fewest_ahead", FewestAhead.make, kind="heuristic")
register_intruders("least_defended", LeastDefended.make, kind="heuristic")
register_intruders("split_away", SplitAway.make, kind="heuristic")
register_intruders("learned", LearnedIntruders.make, kind="learned")
register_intruders("mixture", IntruderMixture.make, kind="mixture")
register_intruders("search", SearchingIntruders.make, kind="search")
