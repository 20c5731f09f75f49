"""The solar services: panels and their baselines, the fleet model's training, robots and
the cleaning queue, labels, history and events; the routers call these, these call ``core``."""
