"""Interactive distillation: one loop (BC, DAgger, VIPER and Imitation-BT are its settings)
and its beta schedules."""


def __getattr__(name: str) -> object:
    from ibt import _submodule

    return _submodule(__name__, name)
