"""Interactive distillation: one loop (BC, DAgger, VIPER and Imitation-BT are its settings)
and its beta schedules."""
