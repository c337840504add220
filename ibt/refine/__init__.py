"""Refinement by return (Imitation-BT+): a distilled tree's thresholds, leaf actions and
shape tuned on episodes."""
