"""Logic synthesis: decision tree -> rules -> Espresso -> Behavior Tree, with the baselines
and the decision list."""
