"""Stable-Baselines3 experts: loading a checkpoint as an `Expert`, training and recording them."""
