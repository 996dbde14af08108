"""iLQR: cost, backward pass, line search, settings, the driver (init / step / terminate)
and its stopping rules, state, result and checkpoints."""
