"""Studies over the controllers: gain tuning, error–effort fronts, adversarial disturbance
search, the control-rate study, probes of trained policies."""
